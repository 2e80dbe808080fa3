//! Appending flatbuffer tables to the end of a buffer, for [`super::rewrite`].
//!
//! Every reference in a flatbuffer is a forward offset from where it is stored (vtable
//! references are signed), so new tables can be appended after everything else and
//! reached from existing fields or vector slots that are patched to point at them. A
//! table is written as its vtable, then the table (every field in a 4-byte slot), then
//! its children (vectors, strings, sub-tables), each after the field that refers to it.

/// A field value of an appended table.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// A `ubyte`/`byte`/`bool` field.
    U8(u8),
    /// A 32-bit scalar field (`int`, `uint`).
    U32(u32),
    /// A vector of `int`.
    I32s(Vec<i32>),
    /// A vector of `ubyte`, its data aligned to 16 bytes.
    Bytes(Vec<u8>),
    /// A string.
    Str(String),
    /// A sub-table: its fields.
    Table(Vec<(u16, Value)>),
}

fn pad_to(b: &mut Vec<u8>, align: usize) {
    while !b.len().is_multiple_of(align) {
        b.push(0);
    }
}

/// Stores at `at` the forward offset to `target`.
pub fn set_forward(b: &mut [u8], at: usize, target: usize) -> Option<()> {
    let rel = u32::try_from(target.checked_sub(at)?).ok()?;
    b.get_mut(at..at + 4)?.copy_from_slice(&rel.to_le_bytes());
    Some(())
}

/// Appends a vector: its length (u32) and `items`, the items aligned to `align`.
/// Returns the vector's position (its length prefix).
pub fn append_vector(b: &mut Vec<u8>, len: usize, items: &[u8], align: usize) -> usize {
    while !(b.len() + 4).is_multiple_of(align) {
        b.push(0);
    }
    let at = b.len();
    b.extend_from_slice(&(len as u32).to_le_bytes());
    b.extend_from_slice(items);
    at
}

/// Appends a table with `fields` (vtable offsets, the generated `VT_*` constants, and
/// values); returns the table's position. `None` if an offset does not fit.
pub fn append_table(b: &mut Vec<u8>, fields: &[(u16, Value)]) -> Option<usize> {
    // The vtable: its size, the table's size, then a field offset per slot.
    let slots = fields
        .iter()
        .map(|(vt, _)| usize::from(*vt).saturating_sub(4) / 2 + 1)
        .max()
        .unwrap_or(0);
    let table_len = 4 + 4 * fields.len();
    let mut entries = vec![0_u16; slots];
    for (k, (vt, _)) in fields.iter().enumerate() {
        entries[usize::from(*vt).checked_sub(4)? / 2] = (4 + 4 * k) as u16;
    }
    pad_to(b, 2);
    // The table must start 4-aligned right after the vtable: pad before the vtable.
    let vtable_len = 4 + 2 * slots;
    while !(b.len() + vtable_len).is_multiple_of(4) {
        b.extend_from_slice(&[0, 0]);
    }
    let vtable = b.len();
    b.extend_from_slice(&(vtable_len as u16).to_le_bytes());
    b.extend_from_slice(&(table_len as u16).to_le_bytes());
    for e in entries {
        b.extend_from_slice(&e.to_le_bytes());
    }
    let table = b.len();
    b.extend_from_slice(&i32::try_from(table - vtable).ok()?.to_le_bytes());
    for (_, value) in fields {
        match value {
            Value::U8(v) => b.extend_from_slice(&[*v, 0, 0, 0]),
            Value::U32(v) => b.extend_from_slice(&v.to_le_bytes()),
            _ => b.extend_from_slice(&[0; 4]),
        }
    }
    for (k, (_, value)) in fields.iter().enumerate() {
        let field = table + 4 + 4 * k;
        let child = match value {
            Value::U8(_) | Value::U32(_) => continue,
            Value::I32s(v) => {
                let items: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
                append_vector(b, v.len(), &items, 4)
            }
            Value::Bytes(v) => append_vector(b, v.len(), v, 16),
            Value::Str(s) => {
                let mut items = s.as_bytes().to_vec();
                items.push(0);
                append_vector(b, s.len(), &items, 4)
            }
            Value::Table(sub) => append_table(b, sub)?,
        };
        set_forward(b, field, child)?;
    }
    Some(table)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tract_tflite::tflite;

    #[test]
    fn an_appended_table_reads_back_through_the_generated_accessors() {
        // A root offset, then the table.
        let mut b = vec![0_u8; 8];
        let table = append_table(
            &mut b,
            &[
                (tflite::Tensor::VT_SHAPE, Value::I32s(vec![1, 7, 7, 3])),
                (
                    tflite::Tensor::VT_TYPE_,
                    Value::U8(tflite::TensorType::INT32.0 as u8),
                ),
                (tflite::Tensor::VT_BUFFER, Value::U32(5)),
                (tflite::Tensor::VT_NAME, Value::Str("perm".into())),
            ],
        )
        .expect("fits");
        set_forward(&mut b, 0, table).expect("fits");
        let tensor = flatbuffers::root::<tflite::Tensor>(&b).expect("verifies");
        assert_eq!(
            tensor.shape().expect("shape").iter().collect::<Vec<_>>(),
            vec![1, 7, 7, 3]
        );
        assert_eq!(tensor.type_(), tflite::TensorType::INT32);
        assert_eq!((tensor.buffer(), tensor.name()), (5, Some("perm")));
    }
}
