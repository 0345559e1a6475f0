#!/usr/bin/env bash
# Makes or extends an SROS2 keystore with the openssl CLI alone, in the layout and formats that
# `ros2 security create_keystore` and `ros2 security create_enclave` write, so either tool can
# extend a keystore the other made.
#
#   launch_scripts/make_keystore.sh [--topics FILE] [--force] KEYSTORE ENCLAVE [ENCLAVE ...]
#
#   KEYSTORE      keystore directory; made if missing, its CA reused if present
#   ENCLAVE       enclave path, e.g. /dc_loc or /robot1/dc_loc (the node's --enclave)
#   --topics FILE permissions that allow only the ROS names listed in FILE, one per line:
#                   publish /topic     subscribe /topic
#                   reply /service     (service server)
#                   request /service   (service client)
#                   node /ns/name      (that node's parameter services)
#                 '#' starts a comment; '*' and '?' are wildcards. Every node also gets rt/rosout
#                 (publish), rt/parameter_events (both), rt/clock (subscribe) and ros_discovery_info
#                 (both). Without --topics an enclave may use every topic, service and action.
#   --force       make a new key and certificate for each ENCLAVE even if it has them
#   --payload-protection NONE|SIGN|ENCRYPT
#                 governance.xml's data_protection_kind (default, as sros2: ENCRYPT). With NONE
#                 every DATA submessage is still encrypted whole (metadata_protection_kind ENCRYPT)
#
# ROS_DOMAIN_ID (default 0) is the domain that governance and permissions name. Files that exist
# are kept: the CA, governance.xml, an enclave's key.pem. governance.p7s is signed again when it is
# missing, older than governance.xml or not signed by the permissions CA; an enclave's cert.pem is
# issued again when it is missing or does not match key.pem, the enclave path or the identity CA;
# permissions.xml and permissions.p7s are always written anew, as create_enclave does.
#
# Formats follow sros2 0.13.0, the release series of ROS 2 Jazzy (github.com/ros2/sros2, commit
# e349fcf2ab68b97664295b71e41f1b86aa1034ab: sros2/keystore/_keystore.py, _enclave.py,
# _permission.py, sros2/_utilities.py, policy/defaults/dds/governance.xml,
# policy/defaults/policy.xml, policy/templates/dds/permissions.xsl):
# - one self-signed CA, CN=sros2CA, used as both identity and permissions CA through symlinks;
# - every key EC prime256v1 (DDS Security 9.3.1) in unencrypted PKCS#8 PEM; certificates signed
#   with ECDSA-SHA256, random serial, valid from one day before now for 3650 days; the CA's only
#   extension is a critical basicConstraints CA:TRUE, pathlen:1, an enclave's a non-critical
#   CA:FALSE; an enclave certificate's subject is CN=<enclave path>;
# - governance.xml and permissions.xml are S/MIME signed by the permissions CA: multipart/signed,
#   detached, text/plain, SHA-256, signer certificate included, CRLF line ends.
set -euo pipefail

prog=make_keystore.sh
ca_subject=sros2CA
ca_days_before=1
validity_days=3650
# Parameter services of a node (sros2's node policy, test/policies/common/node/parameters.xml).
parameter_services=(describe_parameters get_parameter_types get_parameters list_parameters
    set_parameters set_parameters_atomically)

die() {
    echo "$prog: $*" >&2
    exit 1
}

# "FILE is missing", naming what FILE points to when it is a dangling symlink.
missing() {
    if [ -L "$1" ]; then echo "$1 is missing (a symlink to $(readlink "$1"), which does not exist)"
    else echo "$1 is missing"; fi
}

usage() {
    sed -n '2,30p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
}

# --- Arguments ------------------------------------------------------------------------------------

topics_file=""
force=0
payload_protection=""
positional=()
while [ $# -gt 0 ]; do
    case $1 in
        -h | --help) usage; exit 0 ;;
        --topics) [ $# -ge 2 ] || die "--topics needs a file"; topics_file=$2; shift 2 ;;
        --topics=*) topics_file=${1#--topics=}; shift ;;
        --force) force=1; shift ;;
        --payload-protection)
            [ $# -ge 2 ] || die "--payload-protection needs NONE, SIGN or ENCRYPT"
            payload_protection=$2; shift 2 ;;
        --) shift; positional+=("$@"); break ;;
        -*) die "unknown option $1 (see --help)" ;;
        *) positional+=("$1"); shift ;;
    esac
done
[ ${#positional[@]} -ge 2 ] || { usage >&2; exit 2; }
keystore=${positional[0]}
enclaves=("${positional[@]:1}")

case $payload_protection in
    "" | NONE | SIGN | ENCRYPT) ;;
    *) die "--payload-protection must be NONE, SIGN or ENCRYPT, not '$payload_protection'" ;;
esac

command -v openssl > /dev/null || die "openssl not found on PATH"

domain_id=${ROS_DOMAIN_ID:-0}
[[ $domain_id =~ ^[0-9]+$ ]] && [ "$domain_id" -le 232 ] \
    || die "ROS_DOMAIN_ID must be an integer from 0 to 232, not '$domain_id'"
domain_id=$((10#$domain_id))

# An enclave path is a ROS namespace (sros2 checks it with rclpy's validate_namespace).
for enclave in "${enclaves[@]}"; do
    [ "$enclave" = / ] || [[ $enclave =~ ^(/[A-Za-z_][A-Za-z0-9_]*)+$ ]] \
        || die "enclave '$enclave' is not a ROS namespace: '/' followed by names of letters," \
            "digits and '_' (not starting with a digit), separated by '/'"
done

# --- Topic list -----------------------------------------------------------------------------------

# DDS topic names per direction, ROS names mangled as rmw does: topics rt/<name>; a service's
# request rq/<name>Request and reply rr/<name>Reply.
publish=()
subscribe=()
add_reply() { subscribe+=("rq$1Request"); publish+=("rr$1Reply"); }
add_request() { publish+=("rq$1Request"); subscribe+=("rr$1Reply"); }

if [ -n "$topics_file" ]; then
    [ -f "$topics_file" ] && [ -r "$topics_file" ] || die "cannot read topic list $topics_file"
    line_no=0
    while IFS= read -r line || [ -n "$line" ]; do
        line_no=$((line_no + 1))
        line=${line%%#*}
        line=${line%$'\r'}
        read -r verb name extra <<< "$line" || true
        [ -n "${verb:-}" ] || continue
        where="$topics_file:$line_no"
        [ -n "${name:-}" ] && [ -z "${extra:-}" ] || die "$where: expected '<verb> <name>', got '$line'"
        if [ "$verb" = node ]; then
            [[ $name =~ ^(/[A-Za-z_][A-Za-z0-9_]*)+$ ]] \
                || die "$where: '$name' is not a fully qualified node name like /dc_loc or /ns/dc_loc"
        else
            [[ $name =~ ^/[A-Za-z0-9_*?/]*[A-Za-z0-9_*?]$ && $name != *//* ]] \
                || die "$where: '$name' is not an absolute ROS name (e.g. /odom, /ns/topic; '*' and '?' match)"
        fi
        case $verb in
            publish) publish+=("rt$name") ;;
            subscribe) subscribe+=("rt$name") ;;
            reply) add_reply "$name" ;;
            request) add_request "$name" ;;
            node)
                for s in "${parameter_services[@]}"; do
                    add_reply "$name/$s"
                    add_request "$name/$s"
                done
                ;;
            *) die "$where: unknown verb '$verb' (publish, subscribe, reply, request or node)" ;;
        esac
    done < "$topics_file"
    # What every node uses (sros2's node policy: logging, time, parameters).
    publish+=(rt/rosout rt/parameter_events)
    subscribe+=(rt/clock rt/parameter_events)
fi

# --- Helpers --------------------------------------------------------------------------------------

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# Runs openssl; on failure names the file it was making and shows openssl's message.
ossl() {
    local target=$1
    shift
    if ! openssl "$@" > "$work/openssl.out" 2>&1; then
        cat "$work/openssl.out" >&2
        die "openssl $1 failed while making $target"
    fi
}

# openssl configuration for issuing certificates with `openssl ca`, the one openssl 3.0 command
# that sets notBefore in the past. Its database lives in $work only: like sros2, the keystore keeps
# no record of issued certificates.
cat > "$work/ca.cnf" << 'EOF'
[ ca ]
default_ca = sros2
[ sros2 ]
database = $ENV::CA_WORK/index.txt
serial = $ENV::CA_WORK/serial
new_certs_dir = $ENV::CA_WORK
default_md = sha256
policy = policy_cn
unique_subject = no
email_in_dn = no
[ policy_cn ]
commonName = supplied
[ ca_ext ]
basicConstraints = critical,CA:TRUE,pathlen:1
subjectKeyIdentifier = none
authorityKeyIdentifier = none
[ enclave_ext ]
basicConstraints = CA:FALSE
subjectKeyIdentifier = none
authorityKeyIdentifier = none
[ req ]
distinguished_name = req_dn
string_mask = utf8only
utf8 = yes
[ req_dn ]
EOF
export CA_WORK=$work

new_key() {
    (umask 077 && ossl "$1" genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 \
        -pkeyopt ec_param_enc:named_curve -out "$1")
}

# issue_cert OUT KEY CN EXTENSIONS [CA_CERT CA_KEY]: a certificate for KEY, self-signed without a CA.
issue_cert() {
    local out=$1 key=$2 cn=$3 ext=$4 ca_cert=${5:-} ca_key=${6:-}
    local now start end
    now=$(date -u +%s)
    start=$(date -u -d "@$((now - ca_days_before * 86400))" +%Y%m%d%H%M%SZ)
    end=$(date -u -d "@$((now + validity_days * 86400))" +%Y%m%d%H%M%SZ)
    : > "$work/index.txt"
    ossl "$out" req -config "$work/ca.cnf" -new -key "$key" -subj "/CN=${cn//\//\\/}" -out "$work/req.pem"
    local signer=(-selfsign -keyfile "$key")
    [ -n "$ca_cert" ] && signer=(-cert "$ca_cert" -keyfile "$ca_key")
    ossl "$out" ca -config "$work/ca.cnf" -batch -notext -rand_serial -preserveDN "${signer[@]}" \
        -extensions "$ext" -startdate "$start" -enddate "$end" -in "$work/req.pem" -out "$out"
}

# S/MIME signature of IN by the permissions CA, written to OUT with CRLF line ends throughout as
# sros2 (python cryptography's PKCS7SignatureBuilder, options Text and DetachedSignature) writes it.
smime_sign() {
    local in=$1 out=$2
    ossl "$out" smime -sign -text -md sha256 -in "$in" -signer "$perm_ca_cert" -inkey "$perm_ca_key" \
        -out "$work/signed.p7s"
    sed 's/\r*$/\r/' "$work/signed.p7s" > "$out"
}

smime_verifies() {
    [ -f "$2" ] && openssl smime -verify -in "$2" -CAfile "$1" -out /dev/null > /dev/null 2>&1
}

same_public_key() {
    [ "$(openssl x509 -in "$1" -noout -pubkey 2> /dev/null)" = "$(openssl pkey -in "$2" -pubout 2> /dev/null)" ]
}

# sros2 writes the certificate's dates into permissions.xml as ISO 8601 without zone (UTC).
cert_date() {
    local d
    d=$(openssl x509 -in "$1" -noout "-$2") || die "cannot read the dates of $1"
    date -u -d "${d#*=}" +%Y-%m-%dT%H:%M:%S
}

# ln -s TARGET LINK, unless LINK already resolves to the same file (as sros2's create_symlink).
link() {
    local target=$1 dst=$2
    if [ -e "$dst" ] && [ "$(dirname "$dst")/$target" -ef "$dst" ]; then return; fi
    rm -f "$dst"
    ln -s "$target" "$dst"
}

# --- Keystore: CA and governance ------------------------------------------------------------------

public=$keystore/public
private=$keystore/private
enclaves_dir=$keystore/enclaves
mkdir -p "$public" "$private" "$enclaves_dir" || die "cannot make the directories of keystore $keystore"

ca_cert=$public/ca.cert.pem
ca_key=$private/ca.key.pem
id_ca_cert=$public/identity_ca.cert.pem
id_ca_key=$private/identity_ca.key.pem
perm_ca_cert=$public/permissions_ca.cert.pem
perm_ca_key=$private/permissions_ca.key.pem

# Identity and permissions CA are the keystore CA through symlinks unless the keystore holds its own
# files for them; the CA is made only when none of it exists.
needs_ca=0
for role in identity permissions; do
    cert=$public/${role}_ca.cert.pem
    key=$private/${role}_ca.key.pem
    if [ -f "$cert" ] && [ -f "$key" ]; then
        same_public_key "$cert" "$key" || die "$key is not the private key of $cert"
    elif [ -f "$cert" ] || [ -f "$key" ]; then
        [ -f "$cert" ] && absent=$key || absent=$cert
        die "$(missing "$absent") while its counterpart exists; restore it, or" \
            "remove both to use $ca_cert"
    else
        needs_ca=1
    fi
done
if [ $needs_ca = 1 ]; then
    if [ ! -f "$ca_cert" ] && [ ! -f "$ca_key" ]; then
        new_key "$work/ca.key.pem"
        issue_cert "$work/ca.cert.pem" "$work/ca.key.pem" "$ca_subject" ca_ext
        mv "$work/ca.key.pem" "$ca_key"
        mv "$work/ca.cert.pem" "$ca_cert"
        echo "made CA $ca_cert"
    elif [ -f "$ca_cert" ] && [ -f "$ca_key" ]; then
        same_public_key "$ca_cert" "$ca_key" || die "$ca_key is not the private key of $ca_cert"
    else
        [ -f "$ca_cert" ] && absent=$ca_key || absent=$ca_cert
        die "$(missing "$absent") while its counterpart exists; restore it, or" \
            "remove both to make a new CA"
    fi
    for role in identity permissions; do
        [ -f "$public/${role}_ca.cert.pem" ] || link ca.cert.pem "$public/${role}_ca.cert.pem"
        [ -f "$private/${role}_ca.key.pem" ] || link ca.key.pem "$private/${role}_ca.key.pem"
    done
fi

# sros2's policy/defaults/dds/governance.xml as lxml writes it back (no XML declaration).
governance=$enclaves_dir/governance.xml
signed_governance=$enclaves_dir/governance.p7s
if [ ! -f "$governance" ]; then
    cat > "$governance" << EOF
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd">
    <domain_access_rules>
        <domain_rule>
            <domains>
              <id>$domain_id</id>
            </domains>
            <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
            <enable_join_access_control>true</enable_join_access_control>
            <discovery_protection_kind>ENCRYPT</discovery_protection_kind>
            <liveliness_protection_kind>ENCRYPT</liveliness_protection_kind>
            <rtps_protection_kind>SIGN</rtps_protection_kind>
            <topic_access_rules>
                <topic_rule>
                    <topic_expression>*</topic_expression>
                    <enable_discovery_protection>true</enable_discovery_protection>
                    <enable_liveliness_protection>true</enable_liveliness_protection>
                    <enable_read_access_control>true</enable_read_access_control>
                    <enable_write_access_control>true</enable_write_access_control>
                    <metadata_protection_kind>ENCRYPT</metadata_protection_kind>
                    <data_protection_kind>ENCRYPT</data_protection_kind>
                </topic_rule>
            </topic_access_rules>
        </domain_rule>
    </domain_access_rules>
</dds>
EOF
    echo "wrote $governance (domain $domain_id)"
fi
# --payload-protection rewrites the topic rule's data_protection_kind (then signed again below).
if [ -n "$payload_protection" ] \
    && ! grep -q "<data_protection_kind>$payload_protection</data_protection_kind>" "$governance"; then
    sed -i "s|<data_protection_kind>[A-Z_]*</data_protection_kind>|<data_protection_kind>$payload_protection</data_protection_kind>|" \
        "$governance"
    echo "set data_protection_kind $payload_protection in $governance"
fi
# Permissions name ROS_DOMAIN_ID; a governance written for another domain lets no participant in.
if ! grep -q "<id>[[:space:]]*$domain_id[[:space:]]*</id>\|<id_range>" "$governance"; then
    echo "$prog: warning: $governance does not name domain $domain_id (ROS_DOMAIN_ID); participants" \
        "with these enclaves will be refused on it: set ROS_DOMAIN_ID to the governance's domain, or" \
        "edit $governance and run again to re-sign it" >&2
fi
if [ "$governance" -nt "$signed_governance" ] || ! smime_verifies "$perm_ca_cert" "$signed_governance"; then
    smime_sign "$governance" "$signed_governance"
    echo "signed $signed_governance"
fi

# --- Enclaves -------------------------------------------------------------------------------------

# Permissions of an enclave without a topic list: sros2's policy/defaults/policy.xml (every topic,
# service and action) through permissions.xsl, which also allows ros_discovery_info for the rmw
# implementations that use it (rmw_fastrtps_cpp, Jazzy's default, among them).
default_rules() {
    cat << EOF
      <allow_rule>
        <domains>
          <id>$domain_id</id>
        </domains>
        <publish>
          <topics>
            <topic>rq/*/_action/cancel_goalRequest</topic>
            <topic>rq/*/_action/get_resultRequest</topic>
            <topic>rq/*/_action/send_goalRequest</topic>
            <topic>rq/*Request</topic>
            <topic>rr/*/_action/cancel_goalReply</topic>
            <topic>rr/*/_action/get_resultReply</topic>
            <topic>rr/*/_action/send_goalReply</topic>
            <topic>rt/*/_action/feedback</topic>
            <topic>rt/*/_action/status</topic>
            <topic>rr/*Reply</topic>
            <topic>rt/*</topic>
          </topics>
        </publish>
        <subscribe>
          <topics>
            <topic>rq/*/_action/cancel_goalRequest</topic>
            <topic>rq/*/_action/get_resultRequest</topic>
            <topic>rq/*/_action/send_goalRequest</topic>
            <topic>rq/*Request</topic>
            <topic>rr/*/_action/cancel_goalReply</topic>
            <topic>rr/*/_action/get_resultReply</topic>
            <topic>rr/*/_action/send_goalReply</topic>
            <topic>rt/*/_action/feedback</topic>
            <topic>rt/*/_action/status</topic>
            <topic>rr/*Reply</topic>
            <topic>rt/*</topic>
          </topics>
        </subscribe>
      </allow_rule>
EOF
}

# Permissions from the topic list, sorted and without duplicates as permissions.xsl writes them.
topic_elements() {
    printf '%s\n' "$@" | LC_ALL=C sort -u | sed 's|.*|            <topic>&</topic>|'
}
listed_rules() {
    cat << EOF
      <allow_rule>
        <domains>
          <id>$domain_id</id>
        </domains>
        <publish>
          <topics>
$(topic_elements "${publish[@]}")
          </topics>
        </publish>
        <subscribe>
          <topics>
$(topic_elements "${subscribe[@]}")
          </topics>
        </subscribe>
      </allow_rule>
EOF
}

write_permissions() {
    local enclave=$1 cert=$2 out=$3
    local not_before not_after
    not_before=$(cert_date "$cert" startdate)
    not_after=$(cert_date "$cert" enddate)
    {
        cat << EOF
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_permissions.xsd">
  <permissions>
    <grant name="$enclave">
      <subject_name>CN=$enclave</subject_name>
      <validity>
        <not_before>$not_before</not_before>
        <not_after>$not_after</not_after>
      </validity>
EOF
        if [ -n "$topics_file" ]; then listed_rules; else default_rules; fi
        cat << EOF
      <allow_rule>
        <domains>
          <id>$domain_id</id>
        </domains>
        <publish>
          <topics>
            <topic>ros_discovery_info</topic>
          </topics>
        </publish>
        <subscribe>
          <topics>
            <topic>ros_discovery_info</topic>
          </topics>
        </subscribe>
      </allow_rule>
      <default>DENY</default>
    </grant>
  </permissions>
</dds>
EOF
    } > "$out"
}

for enclave in "${enclaves[@]}"; do
    rel=${enclave#/}
    dir=$enclaves_dir${rel:+/$rel}
    mkdir -p "$dir" || die "cannot make enclave directory $dir"
    # Relative symlinks to the keystore's public certificates and governance, as sros2 makes them.
    up=../
    depth=$(tr -cd / <<< "$enclave" | wc -c)
    [ -n "$rel" ] || depth=0
    gov_up=""
    for ((i = 0; i < depth; i++)); do up+=../; gov_up+=../; done
    link "${up}public/identity_ca.cert.pem" "$dir/identity_ca.cert.pem"
    link "${up}public/permissions_ca.cert.pem" "$dir/permissions_ca.cert.pem"
    [ -z "$rel" ] || link "${gov_up}governance.p7s" "$dir/governance.p7s"

    cert=$dir/cert.pem
    key=$dir/key.pem
    if [ $force = 1 ] || [ ! -f "$key" ]; then
        new_key "$work/key.pem"
        issue_cert "$work/cert.pem" "$work/key.pem" "$enclave" enclave_ext "$id_ca_cert" "$id_ca_key"
        mv "$work/key.pem" "$key"
        mv "$work/cert.pem" "$cert"
        echo "made key and certificate of $enclave in $dir"
    elif [ ! -f "$cert" ] || ! same_public_key "$cert" "$key" \
        || [ "$(openssl x509 -in "$cert" -noout -subject -nameopt RFC2253 2> /dev/null)" != "subject=CN=$enclave" ] \
        || ! openssl verify -CAfile "$id_ca_cert" "$cert" > /dev/null 2>&1; then
        issue_cert "$work/cert.pem" "$key" "$enclave" enclave_ext "$id_ca_cert" "$id_ca_key"
        mv "$work/cert.pem" "$cert"
        echo "issued a new certificate of $enclave for its existing $key"
    fi

    write_permissions "$enclave" "$cert" "$dir/permissions.xml"
    smime_sign "$dir/permissions.xml" "$dir/permissions.p7s"
    echo "wrote and signed $dir/permissions.xml"
done
