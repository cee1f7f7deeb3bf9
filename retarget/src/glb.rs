//! Appending data to a glTF document held as JSON, and writing it as GLB. The `gltf` crate
//! reads documents and writes the GLB container but has no builder that keeps unknown
//! extensions, so the JSON is edited as `serde_json::Value`.

use serde_json::{Value, json};

pub const ARRAY_BUFFER: u32 = 34962;
pub const ELEMENT_ARRAY_BUFFER: u32 = 34963;
pub const FLOAT: u32 = 5126;
pub const UNSIGNED_INT: u32 = 5125;

/// A document under construction: its JSON and its single binary buffer.
pub struct GlbBuilder {
    pub json: Value,
    pub bin: Vec<u8>,
}

impl GlbBuilder {
    pub fn new(json: Value, bin: Vec<u8>) -> Self {
        Self { json, bin }
    }

    fn pad(&mut self) {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
    }

    /// Appends `item` to the top-level array `key` (made if missing); returns its index.
    pub fn push(&mut self, key: &str, item: Value) -> usize {
        if !self.json.get(key).is_some_and(Value::is_array) {
            self.json[key] = json!([]);
        }
        match self.json[key].as_array_mut() {
            Some(list) => {
                list.push(item);
                list.len() - 1
            }
            None => unreachable!("`{key}` was just made an array"),
        }
    }

    /// A buffer view over `data` (4-byte aligned) in buffer 0.
    pub fn view(&mut self, data: &[u8], target: Option<u32>) -> usize {
        self.pad();
        let mut view = json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": data.len()});
        if let Some(t) = target {
            view["target"] = json!(t);
        }
        self.bin.extend_from_slice(data);
        self.push("bufferViews", view)
    }

    /// A float accessor of `kind` (`SCALAR`, `VEC2`, `VEC3`, `VEC4`) over `values`, with
    /// per-component min and max when `bounds` (required for POSITION and animation input).
    pub fn float_accessor(
        &mut self,
        values: &[f32],
        kind: &str,
        target: Option<u32>,
        bounds: bool,
    ) -> usize {
        let width = match kind {
            "VEC2" => 2,
            "VEC3" => 3,
            "VEC4" => 4,
            _ => 1,
        };
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let view = self.view(&bytes, target);
        let mut accessor = json!({"bufferView": view, "componentType": FLOAT, "count": values.len() / width, "type": kind});
        if bounds {
            let mut lo = vec![f32::INFINITY; width];
            let mut hi = vec![f32::NEG_INFINITY; width];
            for chunk in values.chunks_exact(width) {
                for k in 0..width {
                    lo[k] = lo[k].min(chunk[k]);
                    hi[k] = hi[k].max(chunk[k]);
                }
            }
            if values.is_empty() {
                lo = vec![0.0; width];
                hi = vec![0.0; width];
            }
            accessor["min"] = json!(lo);
            accessor["max"] = json!(hi);
        }
        self.push("accessors", accessor)
    }

    pub fn index_accessor(&mut self, indices: &[u32]) -> usize {
        let bytes: Vec<u8> = indices.iter().flat_map(|v| v.to_le_bytes()).collect();
        let view = self.view(&bytes, Some(ELEMENT_ARRAY_BUFFER));
        self.push("accessors", json!({"bufferView": view, "componentType": UNSIGNED_INT, "count": indices.len(), "type": "SCALAR"}))
    }

    /// An image stored in the binary chunk.
    pub fn image(&mut self, name: &str, encoded: &[u8], mime: &str) -> usize {
        let view = self.view(encoded, None);
        self.push(
            "images",
            json!({"name": name, "bufferView": view, "mimeType": mime}),
        )
    }

    /// The GLB file (the JSON's `buffers` set to the one binary chunk).
    pub fn finish(mut self) -> Result<Vec<u8>, String> {
        self.pad();
        self.json["buffers"] = json!([{"byteLength": self.bin.len()}]);
        let json = serde_json::to_vec(&self.json).map_err(|e| e.to_string())?;
        let glb = gltf::Glb {
            header: gltf::binary::Header {
                magic: *b"glTF",
                version: 2,
                length: 0,
            },
            json: json.into(),
            bin: Some(self.bin.into()),
        };
        glb.to_vec().map_err(|e| e.to_string())
    }
}
