//! The wire messages of posestream (ROS 2 package `posestream_msgs`, in `msgs/`) and the
//! ROS 2 standard messages they use (`std_msgs/Header`, `builtin_interfaces/Time`,
//! mirrored from ROS 2 Humble's `std_msgs` and `builtin_interfaces` packages), plus
//! `visualization_msgs/MarkerArray` ([`visualization`]) for RViz2 and Foxglove, `/tf`'s
//! `tf2_msgs/TFMessage` ([`tf`]), the ROS4HRI messages of REP-155 ([`hri`]), and the
//! camera images the image detector reads ([`sensor`]).
//!
//! Each message is declared once, with [`ros_message!`]: the macro writes the Rust struct
//! (serde, so CDR comes from `cdr-encoding`) and its ROS field list, derived from the
//! Rust field types through [`RosType`]. The `.msg` text lives in `msgs/msg/*.msg`
//! (included here with `include_str!`); `tests/msgs.rs` parses it and checks that it
//! declares exactly these fields, so the two cannot drift.
//!
//! Encoding: CDR little-endian (XCDR1, plain), behind the 4-byte encapsulation header
//! `00 01 00 00`, as ROS 2 puts on the wire and in rosbag2 MCAP files ([`encode`],
//! [`decode`]).
//!
//! Besides the messages, this crate holds the files they are kept in and read from:
//! [`recording`] (rosbag2-compatible MCAP), [`formats`] (pose dictionaries and camera
//! intrinsics, which the math is loaded from), [`npy`] arrays, [`toml_file`] (TOML
//! documents read into typed structs), [`files`] (outputs that never replace an input),
//! [`limits`], the largest sizes taken from a peer or a file, [`names`], ROS 2 names
//! checked, and [`shipped`], the files built into the binary (`builtin:NAME` paths).

pub mod error;
pub mod files;
pub mod formats;
pub mod limits;
pub mod names;
pub mod npy;
pub mod recording;
pub mod salvage;
pub mod shipped;
pub mod toml_file;

mod heatmaps;
pub mod hri;
pub mod sensor;
mod skeleton;
pub mod tf;
pub mod visualization;

pub use heatmaps::{HeatMapEncoding, HeatMaps, HeatMapsView};
pub use sensor::{CompressedImage, Image};
pub use skeleton::{MetricSource, Skeleton3D, Skeleton3DArray, SkeletonState, Units};
pub use visualization::{Marker, MarkerArray};

use byteorder::LittleEndian;
use serde::Serialize;
use serde::de::DeserializeOwned;

/// The 4-byte CDR encapsulation header: representation `CDR_LE`, options 0.
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// A type with a ROS 2 interface name (`float64`, `string[]`, `std_msgs/Header`).
pub trait RosType {
    /// The type as a `.msg` field declares it.
    fn ros_type() -> String;
    /// The messages this type needs, recursively (name, definition text), in first-use
    /// order; primitives need none.
    fn dependencies(_out: &mut Vec<(&'static str, &'static str)>) {}
}

macro_rules! primitive {
    ($($t:ty => $name:literal),* $(,)?) => {
        $(impl RosType for $t {
            fn ros_type() -> String {
                $name.to_string()
            }
        })*
    };
}

primitive! {
    bool => "bool", u8 => "uint8", i8 => "int8", u16 => "uint16", i16 => "int16",
    u32 => "uint32", i32 => "int32", u64 => "uint64", i64 => "int64",
    f32 => "float32", f64 => "float64", String => "string",
}

impl<T: RosType> RosType for Vec<T> {
    fn ros_type() -> String {
        format!("{}[]", T::ros_type())
    }
    fn dependencies(out: &mut Vec<(&'static str, &'static str)>) {
        T::dependencies(out);
    }
}

/// A fixed-size array (`float64[9]`): in CDR its elements without a length.
impl<T: RosType, const N: usize> RosType for [T; N] {
    fn ros_type() -> String {
        format!("{}[{N}]", T::ros_type())
    }
    fn dependencies(out: &mut Vec<(&'static str, &'static str)>) {
        T::dependencies(out);
    }
}

/// One field of a message: its ROS type and name.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Field {
    /// The ROS type (`float64[]`, `std_msgs/Header`).
    pub ros_type: String,
    /// The field name.
    pub name: &'static str,
}

/// A ROS 2 message: name, definition text and fields.
pub trait RosMessage: RosType + Serialize + DeserializeOwned {
    /// The full name, `package/msg/Type` (as rosbag2 and MCAP schemas name it).
    const NAME: &'static str;
    /// The `.msg` text.
    const DEFINITION: &'static str;
    /// Bytes of trailing fields that older versions of the message lack: [`decode`]
    /// reads such an older message with them zero (0: none).
    const ADDED_TAIL: usize = 0;
    /// The fields, in order, derived from the Rust type.
    fn fields() -> Vec<Field>;

    /// The DDS type name ROS 2 uses on the wire: `package::msg::dds_::Type_`.
    fn dds_type_name() -> String {
        let mut parts = Self::NAME.split('/');
        let (pkg, kind, ty) = (
            parts.next().unwrap_or_default(),
            parts.next().unwrap_or_default(),
            parts.next().unwrap_or_default(),
        );
        format!("{pkg}::{kind}::dds_::{ty}_")
    }

    /// The definition with every nested message appended, as the `ros2msg` schema
    /// encoding of MCAP (and rosbag2) stores it: each after a line of 80 `=` and a line
    /// `MSG: package/Type`.
    fn full_definition() -> String {
        let mut deps = Vec::new();
        Self::dependencies(&mut deps);
        let mut text = Self::DEFINITION.trim_end().to_string();
        text.push('\n');
        let me = Self::ros_type();
        for (name, def) in deps.into_iter().filter(|(n, _)| *n != me) {
            text.push_str(&"=".repeat(80));
            text.push_str(&format!("\nMSG: {name}\n"));
            text.push_str(def.trim_end());
            text.push('\n');
        }
        text
    }
}

/// Declares a message: the struct (serde), [`RosType`] and [`RosMessage`].
#[macro_export]
#[doc(hidden)]
macro_rules! ros_message {
    (
        $(#[$meta:meta])*
        $name:ident = $full:literal, $short:literal, $definition:expr $(, added_tail = $tail:literal)?;
        $( $(#[$fmeta:meta])* $field:ident : $ty:ty ),* $(,)?
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, PartialEq, Default, serde::Serialize, serde::Deserialize)]
        pub struct $name {
            $( $(#[$fmeta])* pub $field: $ty, )*
        }

        impl $crate::RosType for $name {
            fn ros_type() -> String {
                $short.to_string()
            }
            fn dependencies(out: &mut Vec<(&'static str, &'static str)>) {
                let mut mine = Vec::new();
                $( <$ty as $crate::RosType>::dependencies(&mut mine); )*
                for d in mine {
                    if !out.contains(&d) {
                        out.push(d);
                    }
                }
                let me = ($short, <$name as $crate::RosMessage>::DEFINITION);
                if !out.contains(&me) {
                    out.push(me);
                }
            }
        }

        impl $crate::RosMessage for $name {
            const NAME: &'static str = $full;
            const DEFINITION: &'static str = $definition;
            $( const ADDED_TAIL: usize = $tail; )?
            fn fields() -> Vec<$crate::Field> {
                vec![$($crate::Field {
                    ros_type: <$ty as $crate::RosType>::ros_type(),
                    name: stringify!($field).trim_start_matches("r#"),
                }),*]
            }
        }
    };
}

ros_message! {
    /// `builtin_interfaces/Time`: seconds and nanoseconds since the epoch.
    Time = "builtin_interfaces/msg/Time", "builtin_interfaces/Time",
        "# Time since the epoch (builtin_interfaces/Time).\nint32 sec\nuint32 nanosec\n";
    /// Whole seconds.
    sec: i32,
    /// Nanoseconds within the second, `[0, 1e9)`.
    nanosec: u32,
}

impl Time {
    /// The time `ns` nanoseconds after the epoch (negative times round down).
    pub fn from_nanos(ns: i64) -> Self {
        let sec = ns.div_euclid(1_000_000_000);
        Self {
            sec: sec.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32,
            nanosec: ns.rem_euclid(1_000_000_000) as u32,
        }
    }

    /// Nanoseconds since the epoch.
    pub fn nanos(&self) -> i64 {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }
}

ros_message! {
    /// `std_msgs/Header`: a time stamp and a coordinate frame id.
    Header = "std_msgs/msg/Header", "std_msgs/Header",
        "# Standard metadata for higher-level stamped data types (std_msgs/Header).\nbuiltin_interfaces/Time stamp\nstring frame_id\n";
    /// The time the data describes.
    stamp: Time,
    /// The coordinate frame.
    frame_id: String,
}

/// Why a message could not be decoded.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    /// Fewer than 4 bytes, or an encapsulation other than CDR little-endian.
    #[error("not a CDR little-endian message (encapsulation header {0:02x?})")]
    Encapsulation(Vec<u8>),
    /// The CDR payload does not hold the message.
    #[error("malformed {message}: {reason}")]
    Cdr {
        /// The message type.
        message: &'static str,
        /// What the decoder found.
        reason: String,
    },
    /// The message decoded but its contents are inconsistent.
    #[error("invalid {message}: {reason}")]
    Invalid {
        /// The message type.
        message: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// Why a message could not be encoded.
#[derive(Debug, thiserror::Error)]
#[error("cannot encode {message}: {reason}")]
pub struct EncodeError {
    /// The message type.
    pub message: &'static str,
    /// What the encoder said.
    pub reason: String,
}

/// Serialises a message to CDR little-endian with the encapsulation header.
pub fn encode<M: RosMessage>(msg: &M) -> Result<Vec<u8>, EncodeError> {
    let mut out = Vec::new();
    encode_into(msg, &mut out)?;
    Ok(out)
}

/// [`encode`] appended to `out` (a buffer reused from message to message).
pub fn encode_into<M: RosMessage>(msg: &M, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    out.extend_from_slice(&CDR_LE_HEADER);
    cdr_encoding::to_writer::<M, LittleEndian, _>(&mut *out, msg).map_err(|e| EncodeError {
        message: M::NAME,
        reason: e.to_string(),
    })
}

/// Decodes a CDR message with its encapsulation header.
pub fn decode<M: RosMessage>(bytes: &[u8]) -> Result<M, DecodeError> {
    decode_with::<M, M>(bytes, |body| {
        cdr_encoding::from_bytes::<M, LittleEndian>(body).map(|(m, _)| m)
    })
}

/// [`decode`] written over `place`: its strings and vectors are reused, so a message
/// decoded over one of its size allocates nothing (but a u8 frame's bytes, which serde
/// reads whole). On an error `place` holds what was read of it.
pub fn decode_into<M: RosMessage>(bytes: &[u8], place: &mut M) -> Result<(), DecodeError> {
    decode_with::<M, ()>(bytes, |body| {
        let mut deserializer = cdr_encoding::CdrDeserializer::<LittleEndian>::new(body);
        M::deserialize_in_place(&mut deserializer, place)
    })
}

/// Checks the encapsulation header and reads the CDR body with `read`; a body that does
/// not read may be an older version of the message, without the fields added at its end:
/// read again with them zero (a copy, on this path only).
fn decode_with<M: RosMessage, T>(
    bytes: &[u8],
    mut read: impl FnMut(&[u8]) -> Result<T, cdr_encoding::Error>,
) -> Result<T, DecodeError> {
    match bytes.get(..4) {
        Some(h) if h == CDR_LE_HEADER => {}
        other => return Err(DecodeError::Encapsulation(other.unwrap_or(bytes).to_vec())),
    }
    let body = &bytes[4..];
    read(body)
        .or_else(|e| {
            if M::ADDED_TAIL == 0 {
                return Err(e);
            }
            let mut older = Vec::with_capacity(body.len() + M::ADDED_TAIL);
            older.extend_from_slice(body);
            older.resize(body.len() + M::ADDED_TAIL, 0);
            read(&older).map_err(|_| e)
        })
        .map_err(|e| DecodeError::Cdr {
            message: M::NAME,
            reason: e.to_string(),
        })
}

/// The `(type, name)` fields a `.msg` text declares, constants and comments left out.
pub fn parse_definition(text: &str) -> Vec<(String, String)> {
    text.lines()
        .map(|l| l.split('#').next().unwrap_or_default().trim())
        .filter(|l| !l.is_empty() && !l.contains('='))
        .filter_map(|l| {
            let mut it = l.split_whitespace();
            Some((it.next()?.to_string(), it.next()?.to_string()))
        })
        .collect()
}
