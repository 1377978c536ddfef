//! ros2msg field types, a parser for schema text, and the CDR layout rules.
//!
//! The parser and layout are written from the CDR rules, independently of the
//! Rust structs, so a test can check that a struct's bytes are the CDR
//! encoding of its schema text rather than trusting one to describe the other.

use core::fmt;

/// A primitive ros2msg type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Primitive {
    /// `uint8`.
    Uint8,
    /// `uint16`.
    Uint16,
    /// `uint32`.
    Uint32,
    /// `uint64`.
    Uint64,
    /// `int32`.
    Int32,
    /// `int64`.
    Int64,
    /// `float32`.
    Float32,
    /// `float64`.
    Float64,
}

impl Primitive {
    /// Bytes of one value.
    pub const fn size(self) -> usize {
        match self {
            Primitive::Uint8 => 1,
            Primitive::Uint16 => 2,
            Primitive::Uint32 | Primitive::Int32 | Primitive::Float32 => 4,
            Primitive::Uint64 | Primitive::Int64 | Primitive::Float64 => 8,
        }
    }

    /// The ros2msg name (`float64`).
    pub const fn name(self) -> &'static str {
        match self {
            Primitive::Uint8 => "uint8",
            Primitive::Uint16 => "uint16",
            Primitive::Uint32 => "uint32",
            Primitive::Uint64 => "uint64",
            Primitive::Int32 => "int32",
            Primitive::Int64 => "int64",
            Primitive::Float32 => "float32",
            Primitive::Float64 => "float64",
        }
    }

    fn from_name(name: &str) -> Option<Primitive> {
        [
            Primitive::Uint8,
            Primitive::Uint16,
            Primitive::Uint32,
            Primitive::Uint64,
            Primitive::Int32,
            Primitive::Int64,
            Primitive::Float32,
            Primitive::Float64,
        ]
        .into_iter()
        .find(|p| p.name() == name)
    }

    /// Formats a little-endian value at the start of `bytes`.
    fn format(self, bytes: &[u8]) -> String {
        fn arr<const N: usize>(b: &[u8]) -> [u8; N] {
            let mut out = [0; N];
            out.copy_from_slice(&b[..N]);
            out
        }
        match self {
            Primitive::Uint8 => bytes[0].to_string(),
            Primitive::Uint16 => u16::from_le_bytes(arr(bytes)).to_string(),
            Primitive::Uint32 => u32::from_le_bytes(arr(bytes)).to_string(),
            Primitive::Uint64 => u64::from_le_bytes(arr(bytes)).to_string(),
            Primitive::Int32 => i32::from_le_bytes(arr(bytes)).to_string(),
            Primitive::Int64 => i64::from_le_bytes(arr(bytes)).to_string(),
            Primitive::Float32 => f32::from_le_bytes(arr(bytes)).to_string(),
            Primitive::Float64 => f64::from_le_bytes(arr(bytes)).to_string(),
        }
    }
}

/// A field type: a primitive or a fixed-size array of one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RosType {
    /// One value.
    Scalar(Primitive),
    /// A fixed number of values (`float64[3]`).
    Array(Primitive, usize),
}

impl RosType {
    /// The element type.
    pub const fn primitive(self) -> Primitive {
        match self {
            RosType::Scalar(p) | RosType::Array(p, _) => p,
        }
    }

    /// Values in the field (1 for a scalar).
    pub const fn len(self) -> usize {
        match self {
            RosType::Scalar(_) => 1,
            RosType::Array(_, n) => n,
        }
    }

    /// True for a zero-length array.
    pub const fn is_empty(self) -> bool {
        self.len() == 0
    }

    /// Bytes of the whole field.
    pub const fn size(self) -> usize {
        self.primitive().size() * self.len()
    }

    /// Formats the value at the start of `bytes` (`[a, b, c]` for arrays).
    pub fn format_value(self, bytes: &[u8]) -> String {
        let p = self.primitive();
        match self {
            RosType::Scalar(_) => p.format(bytes),
            RosType::Array(_, n) => {
                let items: Vec<String> = (0..n).map(|i| p.format(&bytes[i * p.size()..])).collect();
                format!("[{}]", items.join(", "))
            }
        }
    }
}

impl fmt::Display for RosType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RosType::Scalar(p) => f.write_str(p.name()),
            RosType::Array(p, n) => write!(f, "{}[{n}]", p.name()),
        }
    }
}

/// Maps a Rust field type to its ros2msg type.
pub trait RosField {
    const ROS_TYPE: RosType;
}

macro_rules! ros_field {
    ($($ty:ty => $prim:ident),+) => {
        $(
            impl RosField for $ty {
                const ROS_TYPE: RosType = RosType::Scalar(Primitive::$prim);
            }
            impl<const N: usize> RosField for [$ty; N] {
                const ROS_TYPE: RosType = RosType::Array(Primitive::$prim, N);
            }
        )+
    };
}

ros_field!(u8 => Uint8, u16 => Uint16, u32 => Uint32, u64 => Uint64, i32 => Int32, i64 => Int64, f32 => Float32, f64 => Float64);

/// One field of a sample type, as declared.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FieldInfo {
    /// The field's name.
    pub name: &'static str,
    /// Byte offset in the Rust struct.
    pub offset: usize,
    /// Its ros2msg type.
    pub ros_type: RosType,
}

/// A field of parsed schema text with its CDR offset (relative to the body,
/// after the 4-byte encapsulation header).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CdrField {
    /// The field's name.
    pub name: String,
    /// Its ros2msg type.
    pub ros_type: RosType,
    /// Byte offset in the CDR body.
    pub offset: usize,
}

/// Why schema text could not be parsed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SchemaError {
    /// A line that is not `type name` (or a constant).
    #[error("schema line {line}: expected `type name`, found {text:?}")]
    Malformed {
        /// 1-based line number.
        line: usize,
        /// The line.
        text: String,
    },
    /// A type that cannot cross processes (strings, sequences, nested messages).
    #[error("schema line {line}: unsupported type {ty:?} (only fixed-size numeric types cross processes)")]
    UnsupportedType {
        /// 1-based line number.
        line: usize,
        /// The type as written.
        ty: String,
    },
}

/// Parses ros2msg text made of `type name` lines (comments, blank lines and
/// `type NAME=value` constants allowed; constants take no room in a sample).
pub fn parse_schema(text: &str) -> Result<Vec<(RosType, String)>, SchemaError> {
    let mut fields = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() || line.contains('=') {
            continue;
        }
        let mut parts = line.split_whitespace();
        let (Some(ty), Some(name), None) = (parts.next(), parts.next(), parts.next()) else {
            return Err(SchemaError::Malformed { line: i + 1, text: raw.to_string() });
        };
        let unsupported = || SchemaError::UnsupportedType { line: i + 1, ty: ty.to_string() };
        let ros_type = match ty.split_once('[') {
            None => RosType::Scalar(Primitive::from_name(ty).ok_or_else(unsupported)?),
            Some((base, rest)) => {
                let len: usize = rest.strip_suffix(']').and_then(|n| n.parse().ok()).ok_or_else(unsupported)?;
                RosType::Array(Primitive::from_name(base).ok_or_else(unsupported)?, len)
            }
        };
        fields.push((ros_type, name.to_string()));
    }
    Ok(fields)
}

/// Lays the fields out as plain CDR (XCDR1) does: each primitive aligned to
/// its own size relative to the start of the body, fixed arrays inline with
/// no length prefix. Returns the fields with offsets and the body length.
pub fn cdr_layout(fields: &[(RosType, String)]) -> (Vec<CdrField>, usize) {
    let mut offset = 0usize;
    let mut out = Vec::with_capacity(fields.len());
    for (ros_type, name) in fields {
        let align = ros_type.primitive().size();
        offset = offset.div_ceil(align) * align;
        out.push(CdrField { name: name.clone(), ros_type: *ros_type, offset });
        offset += ros_type.size();
    }
    (out, offset)
}
