//! Numeric field types shared by the point cloud file readers (PLY, PCD, npy) and the packed-point
//! message decoders (ROS 2 PointCloud2, foxglove.PointCloud).

/// A fixed-size numeric type of a binary field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl Scalar {
    /// Size in bytes.
    pub(crate) fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::I64 | Self::U64 | Self::F64 => 8,
        }
    }

    /// Whether this is a floating-point type.
    pub(crate) fn is_float(self) -> bool {
        matches!(self, Self::F32 | Self::F64)
    }

    /// Reads one value from the start of `b` (which holds at least [`Scalar::size`] bytes).
    /// 64-bit integers beyond 2⁵³ round to the nearest `f64`.
    pub(crate) fn read(self, b: &[u8], big_endian: bool) -> f64 {
        fn arr<const N: usize>(b: &[u8], big_endian: bool) -> [u8; N] {
            let mut a = [0u8; N];
            a.copy_from_slice(&b[..N]);
            if big_endian {
                a.reverse();
            }
            a
        }
        match self {
            Self::I8 => f64::from(b[0] as i8),
            Self::U8 => f64::from(b[0]),
            Self::I16 => f64::from(i16::from_le_bytes(arr(b, big_endian))),
            Self::U16 => f64::from(u16::from_le_bytes(arr(b, big_endian))),
            Self::I32 => f64::from(i32::from_le_bytes(arr(b, big_endian))),
            Self::U32 => f64::from(u32::from_le_bytes(arr(b, big_endian))),
            Self::I64 => i64::from_le_bytes(arr(b, big_endian)) as f64,
            Self::U64 => u64::from_le_bytes(arr(b, big_endian)) as f64,
            Self::F32 => f64::from(f32::from_le_bytes(arr(b, big_endian))),
            Self::F64 => f64::from_le_bytes(arr(b, big_endian)),
        }
    }
}
