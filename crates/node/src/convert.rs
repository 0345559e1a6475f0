//! The node's own message types (visualization_msgs, diagnostic_msgs; field order exactly as in each
//! `.msg` of ROS 2 Jazzy) and the conversions between ROS messages and the core's types: keyframes and
//! closures as a `MarkerArray`, a submap as a `PointCloud2`, counters as a `DiagnosticArray`.
//! No DDS here: plain serde structs, CDR bytes come from serialising them.

use serde::{Deserialize, Serialize};

use dc_loc_core::msgs::builtin_interfaces::Time;
use dc_loc_core::msgs::geometry_msgs::{Point, Pose, Vector3};
use dc_loc_core::msgs::sensor_msgs::{PointCloud2, PointField};
use dc_loc_core::msgs::std_msgs::Header;
use dc_loc_core::submap::Submap;

/// builtin_interfaces/msg/Duration
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Duration {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds.
    pub nanosec: u32,
}

/// std_msgs/msg/ColorRGBA
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ColorRgba {
    /// Red, 0..1.
    pub r: f32,
    /// Green, 0..1.
    pub g: f32,
    /// Blue, 0..1.
    pub b: f32,
    /// Opacity, 0..1.
    pub a: f32,
}

/// sensor_msgs/msg/CompressedImage (a marker's texture; unused, empty).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct CompressedImage {
    /// Stamp and frame.
    pub header: Header,
    /// Image format.
    pub format: String,
    /// Image bytes.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// visualization_msgs/msg/UVCoordinate
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct UvCoordinate {
    /// u.
    pub u: f32,
    /// v.
    pub v: f32,
}

/// visualization_msgs/msg/MeshFile
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct MeshFile {
    /// File name.
    pub filename: String,
    /// File bytes.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// visualization_msgs/msg/Marker (Jazzy).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Marker {
    /// Stamp and frame.
    pub header: Header,
    /// Namespace.
    pub ns: String,
    /// Id within the namespace.
    pub id: i32,
    /// `Marker::*` shape.
    pub r#type: i32,
    /// ADD (0), DELETE (2), DELETEALL (3).
    pub action: i32,
    /// Pose of the marker.
    pub pose: Pose,
    /// Scale, m.
    pub scale: Vector3,
    /// Colour.
    pub color: ColorRgba,
    /// Lifetime (0: forever).
    pub lifetime: Duration,
    /// Follow the frame.
    pub frame_locked: bool,
    /// Points (lists, strips).
    pub points: Vec<Point>,
    /// Per-point colours.
    pub colors: Vec<ColorRgba>,
    /// Texture resource.
    pub texture_resource: String,
    /// Texture.
    pub texture: CompressedImage,
    /// Texture coordinates.
    pub uv_coordinates: Vec<UvCoordinate>,
    /// Text.
    pub text: String,
    /// Mesh resource.
    pub mesh_resource: String,
    /// Mesh file.
    pub mesh_file: MeshFile,
    /// Use the mesh's materials.
    pub mesh_use_embedded_materials: bool,
}

impl Marker {
    /// LINE_LIST
    pub const LINE_LIST: i32 = 5;
    /// SPHERE_LIST
    pub const SPHERE_LIST: i32 = 7;
}

/// visualization_msgs/msg/MarkerArray
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct MarkerArray {
    /// The markers.
    pub markers: Vec<Marker>,
}

/// diagnostic_msgs/msg/KeyValue
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct KeyValue {
    /// Key.
    pub key: String,
    /// Value.
    pub value: String,
}

/// diagnostic_msgs/msg/DiagnosticStatus
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// OK (0), WARN (1), ERROR (2), STALE (3).
    pub level: u8,
    /// Component name.
    pub name: String,
    /// Summary.
    pub message: String,
    /// Hardware id.
    pub hardware_id: String,
    /// Values.
    pub values: Vec<KeyValue>,
}

impl DiagnosticStatus {
    /// OK
    pub const OK: u8 = 0;
    /// WARN
    pub const WARN: u8 = 1;
    /// ERROR
    pub const ERROR: u8 = 2;
}

/// diagnostic_msgs/msg/DiagnosticArray
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DiagnosticArray {
    /// Stamp.
    pub header: Header,
    /// One status per component.
    pub status: Vec<DiagnosticStatus>,
}

/// A keyframe or closure end for the markers: position in the odometry frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerPoint {
    /// x, m.
    pub x: f64,
    /// y, m.
    pub y: f64,
}

/// Keyframes (a sphere list) and loop edges (a line list between the two keyframes' odometry positions)
/// in `frame_id` (the odometry frame).
pub fn markers(
    stamp: Time,
    frame_id: &str,
    keyframes: &[MarkerPoint],
    edges: &[(MarkerPoint, MarkerPoint)],
) -> MarkerArray {
    let header = Header {
        stamp,
        frame_id: frame_id.to_string(),
    };
    let point = |p: &MarkerPoint| Point {
        x: p.x,
        y: p.y,
        z: 0.0,
    };
    let kf = Marker {
        header: header.clone(),
        ns: "keyframes".into(),
        id: 0,
        r#type: Marker::SPHERE_LIST,
        pose: Pose::default(),
        scale: Vector3 {
            x: 1.0,
            y: 1.0,
            z: 1.0,
        },
        color: ColorRgba {
            r: 0.2,
            g: 0.5,
            b: 1.0,
            a: 1.0,
        },
        points: keyframes.iter().map(point).collect(),
        ..Marker::default()
    };
    let lines = Marker {
        header,
        ns: "loop_closures".into(),
        id: 1,
        r#type: Marker::LINE_LIST,
        pose: Pose::default(),
        scale: Vector3 {
            x: 0.3,
            y: 0.0,
            z: 0.0,
        },
        color: ColorRgba {
            r: 1.0,
            g: 0.3,
            b: 0.1,
            a: 1.0,
        },
        points: edges
            .iter()
            .flat_map(|(a, b)| [point(a), point(b)])
            .collect(),
        ..Marker::default()
    };
    MarkerArray {
        markers: vec![kf, lines],
    }
}

/// The compensated submap as a PointCloud2 (fields x, y, z, v_r as float32) in the body frame at its
/// newest scan, stamped with that scan's time.
pub fn submap_cloud(submap: &Submap, frame_id: &str) -> PointCloud2 {
    let fields = ["x", "y", "z", "v_r"]
        .iter()
        .enumerate()
        .map(|(i, n)| PointField {
            name: (*n).into(),
            offset: 4 * i as u32,
            datatype: PointField::FLOAT32,
            count: 1,
        })
        .collect();
    let mut data = Vec::with_capacity(submap.points.len() * 16);
    for q in &submap.points {
        for v in [q.p.x, q.p.y, q.p.z, q.v_r] {
            data.extend_from_slice(&(v as f32).to_le_bytes());
        }
    }
    let n = submap.points.len() as u32;
    PointCloud2 {
        header: Header {
            stamp: submap.anchor_stamp.into(),
            frame_id: frame_id.to_string(),
        },
        height: 1,
        width: n,
        fields,
        is_bigendian: false,
        point_step: 16,
        row_step: 16 * n,
        data,
        is_dense: true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marker_and_diagnostics_cdr_roundtrip() {
        let m = markers(
            Time { sec: 3, nanosec: 4 },
            "odom",
            &[MarkerPoint { x: 1.0, y: 2.0 }],
            &[(
                MarkerPoint { x: 1.0, y: 2.0 },
                MarkerPoint { x: 3.0, y: 4.0 },
            )],
        );
        assert_eq!(m.markers[1].points.len(), 2);
        let bytes = cdr_encoding::to_vec::<_, byteorder::LittleEndian>(&m).unwrap();
        let (back, _) =
            cdr_encoding::from_bytes::<MarkerArray, byteorder::LittleEndian>(&bytes).unwrap();
        assert_eq!(back, m);
        let d = DiagnosticArray {
            header: Header::default(),
            status: vec![DiagnosticStatus {
                level: DiagnosticStatus::WARN,
                name: "dc_loc: input".into(),
                message: "m".into(),
                hardware_id: String::new(),
                values: vec![KeyValue {
                    key: "k".into(),
                    value: "v".into(),
                }],
            }],
        };
        let bytes = cdr_encoding::to_vec::<_, byteorder::LittleEndian>(&d).unwrap();
        let (back, _) =
            cdr_encoding::from_bytes::<DiagnosticArray, byteorder::LittleEndian>(&bytes).unwrap();
        assert_eq!(back, d);
    }
}
