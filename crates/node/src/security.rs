//! DDS Security as ROS 2 sets it up (SROS2): which enclave of an sros2 keystore the participant
//! authenticates with, is authorised by and encrypts with, or none.
//!
//! As rcl reads it: security is on when `ROS_SECURITY_ENABLE` is exactly `true`; the strategy is
//! Enforce when `ROS_SECURITY_STRATEGY` is exactly `Enforce`, Permissive otherwise; the enclave is
//! `ROS_SECURITY_ENCLAVE_OVERRIDE`, else `--ros-args --enclave`, else `/`; its directory is
//! `$ROS_SECURITY_KEYSTORE/enclaves/<enclave>`, holding the six files of [`ENCLAVE_FILES`]. Enforce
//! refuses to start without every one of them (naming the file and why); Permissive warns and runs
//! unsecured. Whether the files are valid (certificates signed by their CA, signed governance and
//! permissions that allow the node's topics) the DDS participant checks when it is made.

use std::path::{Path, PathBuf};

use super::args::ArgsError;

/// The files of an enclave, as sros2 writes them and rmw_dds_common looks them up.
pub const ENCLAVE_FILES: [&str; 6] = [
    "identity_ca.cert.pem",
    "cert.pem",
    "key.pem",
    "permissions_ca.cert.pem",
    "governance.p7s",
    "permissions.p7s",
];

/// The security settings ROS 2 takes from the environment.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SecurityEnv {
    /// `ROS_SECURITY_ENABLE=true`.
    pub enable: bool,
    /// `ROS_SECURITY_STRATEGY=Enforce` (else Permissive).
    pub enforce: bool,
    /// `ROS_SECURITY_KEYSTORE`.
    pub keystore: Option<PathBuf>,
    /// `ROS_SECURITY_ENCLAVE_OVERRIDE`.
    pub enclave_override: Option<String>,
}

impl SecurityEnv {
    /// Reads the variables through `get` (normally `std::env::var`).
    pub fn from_env(get: impl Fn(&str) -> Option<String>) -> Self {
        let set = |k: &str| get(k).filter(|v| !v.is_empty());
        SecurityEnv {
            enable: get("ROS_SECURITY_ENABLE").as_deref() == Some("true"),
            enforce: get("ROS_SECURITY_STRATEGY").as_deref() == Some("Enforce"),
            keystore: set("ROS_SECURITY_KEYSTORE").map(PathBuf::from),
            enclave_override: set("ROS_SECURITY_ENCLAVE_OVERRIDE"),
        }
    }

    /// The enclave directory the participant is secured with (`None`: unsecured), given the
    /// `--enclave` argument. Enforce without a usable enclave is an error naming the cause;
    /// Permissive logs the cause as a warning and runs unsecured.
    pub fn enclave_dir(&self, enclave_arg: Option<&str>) -> Result<Option<PathBuf>, ArgsError> {
        if !self.enable {
            return Ok(None);
        }
        let enclave = self
            .enclave_override
            .as_deref()
            .or(enclave_arg)
            .unwrap_or("/");
        match self.find(enclave) {
            Ok(dir) => Ok(Some(dir)),
            Err(why) if self.enforce => Err(ArgsError::Security(format!(
                "ROS_SECURITY_STRATEGY=Enforce: {why}"
            ))),
            Err(why) => {
                log::warn!(
                    "ROS_SECURITY_ENABLE=true, ROS_SECURITY_STRATEGY not Enforce: {why}; running \
                     unsecured"
                );
                Ok(None)
            }
        }
    }

    /// The enclave's directory, when it holds every file readable.
    fn find(&self, enclave: &str) -> Result<PathBuf, String> {
        let keystore = self
            .keystore
            .as_deref()
            .ok_or("ROS_SECURITY_KEYSTORE is not set")?;
        if !enclave.starts_with('/') {
            return Err(format!(
                "enclave `{enclave}` is not an absolute name (e.g. `/dc_loc`)"
            ));
        }
        let dir = keystore
            .join("enclaves")
            .join(enclave.trim_start_matches('/'));
        if !dir.is_dir() {
            return Err(format!(
                "no enclave `{enclave}` in the keystore: {} is not a directory",
                dir.display()
            ));
        }
        for file in ENCLAVE_FILES {
            readable(&dir.join(file))?;
        }
        Ok(dir)
    }
}

/// `Ok` when `path` opens for reading, else why not, naming it.
fn readable(path: &Path) -> Result<(), String> {
    std::fs::File::open(path)
        .map(drop)
        .map_err(|e| format!("{}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env(enable: &str, strategy: &str, keystore: &Path) -> SecurityEnv {
        let vars = [
            ("ROS_SECURITY_ENABLE", enable.to_string()),
            ("ROS_SECURITY_STRATEGY", strategy.to_string()),
            ("ROS_SECURITY_KEYSTORE", keystore.display().to_string()),
        ];
        SecurityEnv::from_env(|k| vars.iter().find(|(n, _)| *n == k).map(|(_, v)| v.clone()))
    }

    /// Enforce finds the enclave of `--enclave` (or the override) with its six files, and names the
    /// missing file otherwise; Permissive runs unsecured; security off ignores the keystore.
    #[test]
    fn the_enclave_is_found_or_its_missing_file_named() {
        let keystore = std::env::temp_dir().join(format!("dc_loc_keystore_{}", std::process::id()));
        let dir = keystore.join("enclaves/robots/car1");
        std::fs::create_dir_all(&dir).unwrap();
        for f in &ENCLAVE_FILES[..5] {
            std::fs::write(dir.join(f), "x").unwrap();
        }
        let enforce = env("true", "Enforce", &keystore);
        let e = enforce.enclave_dir(Some("/robots/car1")).unwrap_err();
        assert!(e.to_string().contains("permissions.p7s"), "{e}");
        assert_eq!(
            env("true", "Permissive", &keystore).enclave_dir(Some("/robots/car1")),
            Ok(None)
        );
        std::fs::write(dir.join("permissions.p7s"), "x").unwrap();
        assert_eq!(
            enforce.enclave_dir(Some("/robots/car1")),
            Ok(Some(dir.clone()))
        );
        // The root enclave `/` is the keystore's `enclaves/` itself.
        let e = enforce.enclave_dir(None).unwrap_err();
        assert!(
            e.to_string().contains("enclaves/identity_ca.cert.pem"),
            "{e}"
        );
        let overridden = SecurityEnv {
            enclave_override: Some("/robots/car1".into()),
            ..enforce.clone()
        };
        assert_eq!(overridden.enclave_dir(Some("/other")), Ok(Some(dir)));
        assert_eq!(env("1", "Enforce", &keystore).enclave_dir(None), Ok(None));
        let unset = SecurityEnv {
            keystore: None,
            ..enforce
        };
        let e = unset.enclave_dir(None).unwrap_err();
        assert!(e.to_string().contains("ROS_SECURITY_KEYSTORE"), "{e}");
        std::fs::remove_dir_all(&keystore).unwrap();
    }
}
