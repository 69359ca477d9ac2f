//! RIHS01 type hashes (REP-2011): what Iron and later distros put in a topic's rmw_zenoh key and liveliness
//! token, so that a subscriber only matches a publisher of the same type definition. The hash is SHA-256
//! over a canonical JSON of the type's description (its fields, then every type it references, sorted by
//! name), written as `rosidl_generator_type_description` writes it: Python's `json.dumps` with
//! separators `", "` and `": "`, keys in declaration order, no default values, no constants.
//!
//! [`DESCRIPTIONS`] holds the fields of the five published types and of the types they reference (the
//! Jazzy definitions, which Kilted keeps for these types); the tests check that [`rihs01`] reproduces the
//! published hashes, and that the constants in [`super::TOPICS`] are what it computes.
use sha2::{Digest, Sha256};

/// `type_description_interfaces/FieldType` ids of the field kinds these messages use.
pub mod field {
    /// A nested message.
    pub const NESTED: u8 = 1;
    /// uint8.
    pub const UINT8: u8 = 3;
    /// int32.
    pub const INT32: u8 = 6;
    /// uint32.
    pub const UINT32: u8 = 7;
    /// float64 (IDL double).
    pub const FLOAT64: u8 = 11;
    /// bool.
    pub const BOOL: u8 = 15;
    /// string (unbounded).
    pub const STRING: u8 = 17;
    /// Added to an id: a fixed-size array (`float64[9]`), the size in `capacity`.
    pub const ARRAY: u8 = 48;
    /// Added to an id: an unbounded sequence (`uint8[]`).
    pub const SEQUENCE: u8 = 144;
}

/// One field of a message: name, FieldType id, array capacity, nested type (`pkg/msg/Type`, or "").
pub type Field = (&'static str, u8, u32, &'static str);

/// A message type: its full name (`pkg/msg/Type`) and its fields in declaration order.
pub type Description = (&'static str, &'static [Field]);

use field::*;

const HEADER: Field = ("header", NESTED, 0, "std_msgs/msg/Header");

/// The five published types and the types they reference.
pub const DESCRIPTIONS: &[Description] = &[
    ("builtin_interfaces/msg/Time", &[("sec", INT32, 0, ""), ("nanosec", UINT32, 0, "")]),
    ("std_msgs/msg/Header", &[("stamp", NESTED, 0, "builtin_interfaces/msg/Time"), ("frame_id", STRING, 0, "")]),
    (
        "sensor_msgs/msg/Image",
        &[
            HEADER,
            ("height", UINT32, 0, ""),
            ("width", UINT32, 0, ""),
            ("encoding", STRING, 0, ""),
            ("is_bigendian", UINT8, 0, ""),
            ("step", UINT32, 0, ""),
            ("data", UINT8 + SEQUENCE, 0, ""),
        ],
    ),
    (
        "sensor_msgs/msg/RegionOfInterest",
        &[
            ("x_offset", UINT32, 0, ""),
            ("y_offset", UINT32, 0, ""),
            ("height", UINT32, 0, ""),
            ("width", UINT32, 0, ""),
            ("do_rectify", BOOL, 0, ""),
        ],
    ),
    (
        "sensor_msgs/msg/CameraInfo",
        &[
            HEADER,
            ("height", UINT32, 0, ""),
            ("width", UINT32, 0, ""),
            ("distortion_model", STRING, 0, ""),
            ("d", FLOAT64 + SEQUENCE, 0, ""),
            ("k", FLOAT64 + ARRAY, 9, ""),
            ("r", FLOAT64 + ARRAY, 9, ""),
            ("p", FLOAT64 + ARRAY, 12, ""),
            ("binning_x", UINT32, 0, ""),
            ("binning_y", UINT32, 0, ""),
            ("roi", NESTED, 0, "sensor_msgs/msg/RegionOfInterest"),
        ],
    ),
    (
        "sensor_msgs/msg/PointField",
        &[("name", STRING, 0, ""), ("offset", UINT32, 0, ""), ("datatype", UINT8, 0, ""), ("count", UINT32, 0, "")],
    ),
    (
        "sensor_msgs/msg/PointCloud2",
        &[
            HEADER,
            ("height", UINT32, 0, ""),
            ("width", UINT32, 0, ""),
            ("fields", NESTED + SEQUENCE, 0, "sensor_msgs/msg/PointField"),
            ("is_bigendian", BOOL, 0, ""),
            ("point_step", UINT32, 0, ""),
            ("row_step", UINT32, 0, ""),
            ("data", UINT8 + SEQUENCE, 0, ""),
            ("is_dense", BOOL, 0, ""),
        ],
    ),
    ("geometry_msgs/msg/Vector3", &[("x", FLOAT64, 0, ""), ("y", FLOAT64, 0, ""), ("z", FLOAT64, 0, "")]),
    (
        "geometry_msgs/msg/Quaternion",
        &[("x", FLOAT64, 0, ""), ("y", FLOAT64, 0, ""), ("z", FLOAT64, 0, ""), ("w", FLOAT64, 0, "")],
    ),
    (
        "geometry_msgs/msg/Transform",
        &[
            ("translation", NESTED, 0, "geometry_msgs/msg/Vector3"),
            ("rotation", NESTED, 0, "geometry_msgs/msg/Quaternion"),
        ],
    ),
    (
        "geometry_msgs/msg/TransformStamped",
        &[HEADER, ("child_frame_id", STRING, 0, ""), ("transform", NESTED, 0, "geometry_msgs/msg/Transform")],
    ),
    ("tf2_msgs/msg/TFMessage", &[("transforms", NESTED + SEQUENCE, 0, "geometry_msgs/msg/TransformStamped")]),
    (
        "sensor_msgs/msg/JointState",
        &[
            HEADER,
            ("name", STRING + SEQUENCE, 0, ""),
            ("position", FLOAT64 + SEQUENCE, 0, ""),
            ("velocity", FLOAT64 + SEQUENCE, 0, ""),
            ("effort", FLOAT64 + SEQUENCE, 0, ""),
        ],
    ),
    // the gaze topics (`bridges::zenoh_gaze`): goals in, the state out
    ("geometry_msgs/msg/Point", &[("x", FLOAT64, 0, ""), ("y", FLOAT64, 0, ""), ("z", FLOAT64, 0, "")]),
    ("geometry_msgs/msg/PointStamped", &[HEADER, ("point", NESTED, 0, "geometry_msgs/msg/Point")]),
    ("std_msgs/msg/String", &[("data", STRING, 0, "")]),
];

/// Why a hash could not be computed.
#[derive(Debug, thiserror::Error)]
#[error("{0}: not among the type descriptions")]
pub struct UnknownType(pub String);

fn find<'a>(types: &'a [Description], name: &str) -> Result<&'a Description, UnknownType> {
    types.iter().find(|d| d.0 == name).ok_or_else(|| UnknownType(name.to_string()))
}

fn write_type(out: &mut String, (name, fields): &Description) {
    out.push_str(&format!("{{\"type_name\": \"{name}\", \"fields\": ["));
    for (i, (field, id, capacity, nested)) in fields.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        out.push_str(&format!(
            "{{\"name\": \"{field}\", \"type\": {{\"type_id\": {id}, \"capacity\": {capacity}, \
             \"string_capacity\": 0, \"nested_type_name\": \"{nested}\"}}}}"
        ));
    }
    out.push_str("]}");
}

/// The canonical JSON that the hash of `name` is taken over, from the descriptions in `types`.
pub fn canonical_json(types: &[Description], name: &str) -> Result<String, UnknownType> {
    let main = find(types, name)?;
    // every type reachable through nested fields, once, sorted by name
    let mut refs: Vec<&'static str> = Vec::new();
    let mut todo = vec![main];
    while let Some((_, fields)) = todo.pop() {
        for &(_, _, _, nested) in fields.iter().filter(|f| !f.3.is_empty()) {
            if !refs.contains(&nested) {
                refs.push(nested);
                todo.push(find(types, nested)?);
            }
        }
    }
    refs.sort_unstable();
    let mut out = String::from("{\"type_description\": ");
    write_type(&mut out, main);
    out.push_str(", \"referenced_type_descriptions\": [");
    for (i, r) in refs.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        write_type(&mut out, find(types, r)?);
    }
    out.push_str("]}");
    Ok(out)
}

/// `RIHS01_<sha-256 hex>` of the type `name` (`pkg/msg/Type`) described in `types`.
pub fn rihs01(types: &[Description], name: &str) -> Result<String, UnknownType> {
    let digest = Sha256::digest(canonical_json(types, name)?.as_bytes());
    Ok(digest.iter().fold(String::from("RIHS01_"), |mut s, b| {
        s.push_str(&format!("{b:02x}"));
        s
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reproduces_the_published_hashes() {
        // issue 39 (the Jazzy values that ROS 2's generated code carries) and the hashes of the
        // referenced types that ROS 2's `ros2 topic info -v` and rcl's tests print
        let published = [
            ("sensor_msgs/msg/PointCloud2", "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5"),
            ("sensor_msgs/msg/Image", "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"),
            ("builtin_interfaces/msg/Time", "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197"),
            ("std_msgs/msg/Header", "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01"),
            // rmw_zenoh's docs/design.md (the `chatter` key of demo_nodes_cpp), and the generated code's
            ("std_msgs/msg/String", "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"),
            (
                "geometry_msgs/msg/PointStamped",
                "RIHS01_4c0296af86e01e562e9e0405d138a01537247580076c58ea38d7923ac1045897",
            ),
        ];
        for (name, hash) in published {
            assert_eq!(rihs01(DESCRIPTIONS, name).unwrap(), hash, "{name}");
        }
        // the JSON's shape, on the smallest type
        assert_eq!(
            canonical_json(DESCRIPTIONS, "builtin_interfaces/msg/Time").unwrap(),
            "{\"type_description\": {\"type_name\": \"builtin_interfaces/msg/Time\", \"fields\": [{\"name\": \"sec\", \
             \"type\": {\"type_id\": 6, \"capacity\": 0, \"string_capacity\": 0, \"nested_type_name\": \"\"}}, \
             {\"name\": \"nanosec\", \"type\": {\"type_id\": 7, \"capacity\": 0, \"string_capacity\": 0, \
             \"nested_type_name\": \"\"}}]}, \"referenced_type_descriptions\": []}"
        );
        // a changed field changes the hash; an unknown type is an error
        let mut changed = DESCRIPTIONS.to_vec();
        changed[0] = ("builtin_interfaces/msg/Time", &[("sec", INT32, 0, ""), ("nanosec", INT32, 0, "")]);
        assert_ne!(rihs01(&changed, "sensor_msgs/msg/Image").unwrap(), published[1].1);
        assert!(rihs01(DESCRIPTIONS, "std_msgs/msg/Bool").is_err());
    }

    #[test]
    fn topic_constants_are_the_computed_hashes() {
        #[cfg(feature = "zenoh")]
        let gaze = &crate::bridges::zenoh_gaze::TOPICS[..];
        #[cfg(not(feature = "zenoh"))]
        let gaze = &[][..];
        for t in super::super::TOPICS.iter().chain(gaze) {
            assert_eq!(t.rihs01, rihs01(DESCRIPTIONS, t.type_name).unwrap(), "{}", t.type_name);
        }
    }
}
