//! Reading accessor data (dense and sparse) with every byte range, type and count checked.
//!
//! Written by hand because the `gltf` crate's reader assumes a well-formed file: it hits
//! `unreachable!()` on a component type its attribute does not allow (a `FLOAT` index
//! accessor, a `UNSIGNED_INT` texcoord), subtracts 1 from counts that may be 0, and slices
//! without bounds checks in places. Here a malformed accessor is an error naming it.

use gltf::accessor::{DataType, Dimensions};

/// At most this many components (values) are read from the whole file, so a sparse
/// accessor with no buffer view (which may claim any `count` without holding bytes for it)
/// cannot make the loader allocate without bound. Real puppets: ~50k vertices x 3 x ~300
/// position and normal arrays = 45M.
pub const MAX_COMPONENTS: usize = 1 << 27;

/// Components left to read in this file.
#[derive(Debug)]
pub struct Budget(pub usize);

impl Default for Budget {
    fn default() -> Self {
        Self(MAX_COMPONENTS)
    }
}

impl Budget {
    fn take(&mut self, n: usize, what: &str) -> Result<(), String> {
        if n > self.0 {
            return Err(format!(
                "{what}: the file asks for more than {MAX_COMPONENTS} values in all; a puppet this large is refused"
            ));
        }
        self.0 -= n;
        Ok(())
    }
}

fn component_size(t: DataType) -> usize {
    match t {
        DataType::I8 | DataType::U8 => 1,
        DataType::I16 | DataType::U16 => 2,
        DataType::U32 | DataType::F32 => 4,
    }
}

fn read_component(bytes: &[u8], t: DataType) -> f64 {
    let b = |i: usize| bytes.get(i).copied().unwrap_or(0);
    match t {
        DataType::I8 => f64::from(b(0) as i8),
        DataType::U8 => f64::from(b(0)),
        DataType::I16 => f64::from(i16::from_le_bytes([b(0), b(1)])),
        DataType::U16 => f64::from(u16::from_le_bytes([b(0), b(1)])),
        DataType::U32 => f64::from(u32::from_le_bytes([b(0), b(1), b(2), b(3)])),
        DataType::F32 => f64::from(f32::from_le_bytes([b(0), b(1), b(2), b(3)])),
    }
}

/// glTF's normalised-integer to float rules.
fn normalise(v: f64, t: DataType) -> f64 {
    match t {
        DataType::I8 => (v / 127.0).max(-1.0),
        DataType::U8 => v / 255.0,
        DataType::I16 => (v / 32767.0).max(-1.0),
        DataType::U16 => v / 65535.0,
        DataType::U32 | DataType::F32 => v,
    }
}

fn bytes_of<'b>(
    view: &gltf::buffer::View,
    buffers: &'b [Vec<u8>],
    what: &str,
) -> Result<&'b [u8], String> {
    let data = buffers
        .get(view.buffer().index())
        .ok_or_else(|| format!("{what}: buffer view {} has no buffer", view.index()))?;
    let end = view
        .offset()
        .checked_add(view.length())
        .ok_or_else(|| format!("{what}: buffer view {} overflows", view.index()))?;
    data.get(view.offset()..end).ok_or_else(|| {
        format!(
            "{what}: buffer view {} runs past the end of its buffer",
            view.index()
        )
    })
}

/// `len` bytes of `data` from `at`, if they are all there (no arithmetic can overflow).
fn slice(data: &[u8], at: usize, len: usize) -> Option<&[u8]> {
    data.get(at..at.checked_add(len)?)
}

/// Every component of `accessor` as f64 (integers exact, `normalized` applied when
/// `normalise_ints`), `count x components` long, row by row. `allowed` lists the component
/// types the caller's attribute may have; `dims` the element type it needs.
pub fn read(
    accessor: &gltf::Accessor,
    buffers: &[Vec<u8>],
    allowed: &[DataType],
    dims: Dimensions,
    normalise_ints: bool,
    budget: &mut Budget,
    what: &str,
) -> Result<Vec<f64>, String> {
    let what = format!("{what} (accessor {})", accessor.index());
    let t = accessor.data_type();
    if !allowed.contains(&t) || accessor.dimensions() != dims {
        return Err(format!(
            "{what} is {:?} {:?}; {dims:?} of {} is required",
            t,
            accessor.dimensions(),
            allowed
                .iter()
                .map(|t| format!("{t:?}"))
                .collect::<Vec<_>>()
                .join(" / ")
        ));
    }
    let width = dims.multiplicity();
    let size = component_size(t);
    let element = size * width;
    let count = accessor.count();
    if count == 0 {
        return Err(format!("{what} has count 0 (glTF requires at least 1)"));
    }
    let total = count
        .checked_mul(width)
        .ok_or_else(|| format!("{what}: count {count} overflows"))?;
    budget.take(total, &what)?;
    let normalised = normalise_ints && accessor.normalized();
    let convert = |v: f64| if normalised { normalise(v, t) } else { v };

    let mut values = vec![0.0f64; total];
    if let Some(view) = accessor.view() {
        let data = bytes_of(&view, buffers, &what)?;
        let stride = view.stride().unwrap_or(element);
        if stride < element {
            return Err(format!(
                "{what}: stride {stride} is smaller than its element ({element} bytes)"
            ));
        }
        for i in 0..count {
            let at = i
                .checked_mul(stride)
                .and_then(|v| v.checked_add(accessor.offset()))
                .ok_or_else(|| format!("{what}: offset overflows"))?;
            let bytes = slice(data, at, element).ok_or_else(|| {
                format!(
                    "{what}: element {i} runs past the end of buffer view {}",
                    view.index()
                )
            })?;
            for c in 0..width {
                values[i * width + c] = convert(read_component(&bytes[c * size..], t));
            }
        }
    }
    if let Some(sparse) = accessor.sparse() {
        let n = sparse.count();
        if n == 0 || n > count {
            return Err(format!(
                "{what}: {n} sparse values for {count} elements (1 to {count} allowed)"
            ));
        }
        let indices = sparse.indices();
        let index_type = match indices.index_type() {
            gltf::accessor::sparse::IndexType::U8 => DataType::U8,
            gltf::accessor::sparse::IndexType::U16 => DataType::U16,
            gltf::accessor::sparse::IndexType::U32 => DataType::U32,
        };
        let index_size = component_size(index_type);
        let index_bytes = bytes_of(&indices.view(), buffers, &what)?;
        let value_bytes = bytes_of(&sparse.values().view(), buffers, &what)?;
        let mut previous: Option<usize> = None;
        for k in 0..n {
            let at = k
                .checked_mul(index_size)
                .and_then(|o| indices.offset().checked_add(o));
            let b = at
                .and_then(|at| slice(index_bytes, at, index_size))
                .ok_or_else(|| format!("{what}: sparse index {k} runs past its buffer view"))?;
            let i = read_component(b, index_type) as usize;
            if i >= count {
                return Err(format!(
                    "{what}: sparse index {i} is past its {count} elements"
                ));
            }
            if previous.is_some_and(|p| i <= p) {
                return Err(format!(
                    "{what}: sparse indices must increase (index {k} is {i})"
                ));
            }
            previous = Some(i);
            let at = k
                .checked_mul(element)
                .and_then(|o| sparse.values().offset().checked_add(o));
            let b = at
                .and_then(|at| slice(value_bytes, at, element))
                .ok_or_else(|| format!("{what}: sparse value {k} runs past its buffer view"))?;
            for c in 0..width {
                values[i * width + c] = convert(read_component(&b[c * size..], t));
            }
        }
    } else if accessor.view().is_none() {
        return Err(format!("{what} has neither a buffer view nor sparse data"));
    }
    Ok(values)
}

/// Float values of `N` components per element, every one finite.
pub fn read_vectors<const N: usize>(
    accessor: &gltf::Accessor,
    buffers: &[Vec<u8>],
    allowed: &[DataType],
    budget: &mut Budget,
    what: &str,
) -> Result<Vec<[f32; N]>, String> {
    let dims = match N {
        1 => Dimensions::Scalar,
        2 => Dimensions::Vec2,
        3 => Dimensions::Vec3,
        4 => Dimensions::Vec4,
        16 => Dimensions::Mat4,
        _ => {
            return Err(format!(
                "{what}: {N} components per element is not a glTF type"
            ));
        }
    };
    let values = read(accessor, buffers, allowed, dims, true, budget, what)?;
    let mut out = Vec::with_capacity(values.len() / N);
    for (i, chunk) in values.chunks_exact(N).enumerate() {
        let mut v = [0.0f32; N];
        for (dst, &src) in v.iter_mut().zip(chunk) {
            *dst = src as f32;
            if !dst.is_finite() {
                return Err(format!(
                    "{what} (accessor {}): element {i} is not finite ({chunk:?})",
                    accessor.index()
                ));
            }
        }
        out.push(v);
    }
    Ok(out)
}

/// Unsigned integer scalars (indices) or vectors (joints), un-normalised.
pub fn read_uints(
    accessor: &gltf::Accessor,
    buffers: &[Vec<u8>],
    allowed: &[DataType],
    dims: Dimensions,
    budget: &mut Budget,
    what: &str,
) -> Result<Vec<u32>, String> {
    let values = read(accessor, buffers, allowed, dims, false, budget, what)?;
    Ok(values.into_iter().map(|v| v as u32).collect())
}
