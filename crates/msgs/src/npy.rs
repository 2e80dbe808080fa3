//! NPY arrays in and out (numpy's format, via `npyz`): f32 or f64, C or Fortran order.
//! Every reader checks the shape and finiteness and names the file in its error.

use std::path::Path;

use npyz::WriterBuilder;

use crate::error::ArrayError;

/// A dense array read from an NPY file, in C (row-major) order.
#[derive(Debug, Clone, PartialEq)]
pub struct Array<T> {
    /// Sizes, slowest first.
    pub shape: Vec<usize>,
    /// Values, row-major.
    pub data: Vec<T>,
}

/// Element types that can be read from f32 or f64 files.
pub trait Element: Copy + Default {
    /// Converts from f64.
    fn from_f64(v: f64) -> Self;
    /// Converts from f32.
    fn from_f32(v: f32) -> Self;
    /// True for NaN or infinity.
    fn non_finite(self) -> bool;
}

impl Element for f64 {
    fn from_f64(v: f64) -> Self {
        v
    }
    fn from_f32(v: f32) -> Self {
        f64::from(v)
    }
    fn non_finite(self) -> bool {
        !self.is_finite()
    }
}

impl Element for f32 {
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn from_f32(v: f32) -> Self {
        v
    }
    fn non_finite(self) -> bool {
        !self.is_finite()
    }
}

/// Checks the header text of an NPY file before `npyz` parses it: a plain array's header
/// is one flat dictionary (`{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3)}`),
/// and the Python-literal parser `npyz` uses backtracks for a very long time on deeply
/// nested brackets (a 191-byte file of `{{{{…` took over 20 s: found by fuzzing). Only the
/// bracket structure is checked here; `npyz` reads the rest.
fn check_header(bytes: &[u8]) -> Result<(), String> {
    let (Some(&major), Some(magic)) = (bytes.get(6), bytes.get(..6)) else {
        return Err("not an NPY file (too short)".into());
    };
    if magic != b"\x93NUMPY" {
        return Err("not an NPY file (no \\x93NUMPY magic)".into());
    }
    let (len, start) = match major {
        1 => (
            bytes
                .get(8..10)
                .map(|b| usize::from(u16::from_le_bytes([b[0], b[1]]))),
            10_usize,
        ),
        _ => (
            bytes
                .get(8..12)
                .and_then(|b| usize::try_from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])).ok()),
            12,
        ),
    };
    let header = len
        .and_then(|len| bytes.get(start..start.checked_add(len)?))
        .ok_or("the header is cut short")?;
    let count = |c: u8| header.iter().filter(|&&b| b == c).count();
    if count(b'{') != 1 || count(b'(') > 1 || count(b'[') > 0 {
        return Err("the header is not one flat dictionary of a plain array".into());
    }
    Ok(())
}

/// The largest NPY file read: 256 MiB (32 M f64 values, e.g. 100,000 frames of 17
/// joints' 2-D positions about 27 MB).
pub const MAX_NPY_BYTES: u64 = 256 << 20;

/// Reads an f32/f64 array (a regular file of at most [`MAX_NPY_BYTES`]), rejecting empty
/// arrays and non-finite values.
pub fn read<T: Element>(path: &Path) -> Result<Array<T>, ArrayError> {
    let bytes = posestream_base::files::read_capped(path, MAX_NPY_BYTES).map_err(|source| {
        ArrayError::Io {
            path: path.to_path_buf(),
            source,
        }
    })?;
    from_bytes(&bytes, path)
}

/// Parses an NPY file held in memory (`path` names it in errors), as [`read`] does.
pub fn from_bytes<T: Element>(bytes: &[u8], path: &Path) -> Result<Array<T>, ArrayError> {
    let fmt = |reason: String| ArrayError::Format {
        path: path.to_path_buf(),
        reason,
    };
    check_header(bytes).map_err(fmt)?;
    // `npyz` multiplies the header's shape without checking for overflow (a panic with
    // overflow checks, found by fuzzing; release builds wrap, and the size check below
    // refuses the result): its parsing is contained.
    let file = posestream_base::contain_panics(|| npyz::NpyFile::new(bytes))
        .map_err(|panic| fmt(format!("malformed header ({panic})")))?
        .map_err(|e| fmt(e.to_string()))?;
    let order = file.order();
    let type_str = match file.dtype() {
        npyz::DType::Plain(ts) => ts.to_string(),
        other => return Err(fmt(format!("unsupported dtype {other:?}"))),
    };
    // The header's shape is the file's claim: its size must be countable and fit in the
    // bytes the file holds before anything of that size is allocated.
    let item = if type_str.ends_with('8') { 8 } else { 4 };
    let claimed = file.shape().to_vec();
    let fits = claimed
        .iter()
        .try_fold(item, |n: u64, &s| n.checked_mul(s))
        .is_some_and(|n| n <= bytes.len() as u64);
    if !fits {
        return Err(fmt(format!(
            "the shape {claimed:?} is too large for the file's {} bytes",
            bytes.len()
        )));
    }
    let shape: Vec<usize> = claimed.iter().map(|&s| s as usize).collect();
    let flat: Vec<T> = match type_str.as_str() {
        "<f8" | ">f8" => file
            .into_vec::<f64>()
            .map_err(|e| fmt(e.to_string()))?
            .into_iter()
            .map(T::from_f64)
            .collect(),
        "<f4" | ">f4" => file
            .into_vec::<f32>()
            .map_err(|e| fmt(e.to_string()))?
            .into_iter()
            .map(T::from_f32)
            .collect(),
        other => return Err(fmt(format!("dtype {other} is not f32 or f64"))),
    };
    if flat.is_empty() {
        return Err(ArrayError::Empty {
            path: path.to_path_buf(),
        });
    }
    if let Some(index) = flat.iter().position(|v| v.non_finite()) {
        return Err(ArrayError::NonFinite {
            path: path.to_path_buf(),
            index,
        });
    }
    let data = match order {
        npyz::Order::C => flat,
        npyz::Order::Fortran => fortran_to_c(&flat, &shape),
    };
    Ok(Array { shape, data })
}

/// Reorders a Fortran-order buffer to C order.
fn fortran_to_c<T: Copy + Default>(flat: &[T], shape: &[usize]) -> Vec<T> {
    let n = flat.len();
    let mut out = vec![T::default(); n];
    let mut idx = vec![0usize; shape.len()];
    for (c_pos, slot) in out.iter_mut().enumerate() {
        let mut rem = c_pos;
        for d in (0..shape.len()).rev() {
            idx[d] = rem % shape[d];
            rem /= shape[d];
        }
        let mut f_pos = 0;
        for d in (0..shape.len()).rev() {
            f_pos = f_pos * shape[d] + idx[d];
        }
        *slot = flat[f_pos];
    }
    out
}

/// Checks the array has `expected.len()` dimensions and that each fixed size matches
/// (`None` accepts any size). `what` describes the shape in errors.
pub fn expect_shape<T>(
    a: &Array<T>,
    path: &Path,
    expected: &[Option<usize>],
    what: &str,
) -> Result<(), ArrayError> {
    let ok = a.shape.len() == expected.len()
        && a.shape
            .iter()
            .zip(expected)
            .all(|(s, e)| e.is_none_or(|e| e == *s));
    if ok {
        Ok(())
    } else {
        Err(ArrayError::Shape {
            path: path.to_path_buf(),
            expected: what.to_string(),
            found: a.shape.iter().map(|&s| s as u64).collect(),
        })
    }
}

/// Writes an array of `shape` (C order; f64 or f32), through a
/// [`crate::files::OutputFile`]: an existing file is never left half-written.
pub fn write<T: npyz::Serialize + npyz::AutoSerialize + Copy>(
    path: &Path,
    shape: &[usize],
    data: &[T],
) -> Result<(), ArrayError> {
    let io = |source: std::io::Error| ArrayError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut output = crate::files::OutputFile::create(path, &[]).map_err(|e| match e {
        crate::files::OutputError::Io { source, .. } => io(source),
        other => io(std::io::Error::other(other.to_string())),
    })?;
    {
        let mut w = output.writer();
        let shape64: Vec<u64> = shape.iter().map(|&s| s as u64).collect();
        let mut writer = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&shape64)
            .writer(&mut w)
            .begin_nd()
            .map_err(io)?;
        writer.extend(data.iter().copied()).map_err(io)?;
        writer.finish().map_err(io)?;
        std::io::Write::flush(&mut w).map_err(io)?;
    }
    output.commit().map_err(|e| match e {
        crate::files::OutputError::Io { source, .. } => io(source),
        other => io(std::io::Error::other(other.to_string())),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_checks_shape() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("a.npy");
        let data: Vec<f64> = (0..24).map(f64::from).collect();
        write(&path, &[2, 3, 4], &data).expect("write");
        let a: Array<f64> = read(&path).expect("read");
        assert_eq!(a.shape, vec![2, 3, 4]);
        assert_eq!(a.data, data);
        assert!(expect_shape(&a, &path, &[None, Some(3), Some(4)], "(F, 3, 4)").is_ok());
        assert!(matches!(
            expect_shape(&a, &path, &[None, Some(17), Some(2)], "(F, 17, 2)"),
            Err(ArrayError::Shape { .. })
        ));
    }

    #[test]
    fn rejects_garbage_and_empty_files() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("bad.npy");
        std::fs::write(&path, b"not an npy file").expect("write");
        assert!(matches!(read::<f64>(&path), Err(ArrayError::Format { .. })));
        std::fs::write(&path, b"").expect("write");
        assert!(matches!(read::<f64>(&path), Err(ArrayError::Format { .. })));
        write::<f64>(&path, &[0, 2], &[]).expect("write");
        assert!(matches!(read::<f64>(&path), Err(ArrayError::Empty { .. })));
        write(&path, &[2], &[1.0, f64::NAN]).expect("write");
        assert!(matches!(
            read::<f64>(&path),
            Err(ArrayError::NonFinite { index: 1, .. })
        ));
    }

    #[test]
    fn reorders_fortran_arrays() {
        let flat = [1, 4, 2, 5, 3, 6]; // 2 x 3 [[1,2,3],[4,5,6]] in Fortran order
        assert_eq!(fortran_to_c(&flat, &[2, 3]), vec![1, 2, 3, 4, 5, 6]);
    }
}
