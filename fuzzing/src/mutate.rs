//! A small deterministic mutator: byte flips, interesting numbers, truncation, insertion,
//! deletion, duplication and splicing with another seed, plus edits that know the
//! structure of the input (a JSON value, a CSV cell, a GLB's JSON chunk, a safetensors
//! header and the JSON inside its metadata), which keep the rest of the file valid so
//! that a case reaches past the first check. The same seed always gives the same case.

use serde_json::{Value, json};

/// What a target's inputs are made of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Binary,
    Json,
    Csv,
    /// GLB (a JSON chunk and a binary chunk) or a `.gltf` JSON file.
    Gltf,
    /// Safetensors: a length, a JSON header (with string metadata holding JSON), data.
    Safetensors,
    /// The video target: a mode byte, then JSON, text or a raw stream.
    Video,
}

/// SplitMix64: tiny, fast and the same on every platform.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (0 when `n` is 0).
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next_u64() % n as u64) as usize
        }
    }

    pub fn chance(&mut self, one_in: usize) -> bool {
        self.below(one_in) == 0
    }

    pub fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

/// Numbers that break parsers: zero, signs, type limits, beyond f32, not quite integers.
const NUMBERS: &[&str] = &[
    "0",
    "-0",
    "1",
    "-1",
    "0.5",
    "2",
    "3",
    "4",
    "52",
    "53",
    "68",
    "255",
    "256",
    "65535",
    "65536",
    "1024",
    "4096",
    "16384",
    "16385",
    "2147483647",
    "2147483648",
    "4294967295",
    "4294967296",
    "9007199254740993",
    "18446744073709551615",
    "18446744073709551616",
    "-2147483649",
    "1e10",
    "1e38",
    "3.5e38",
    "1e39",
    "-1e39",
    "1e300",
    "1e-45",
    "1e-300",
    "1.5",
    "-0.5",
    "0.999999",
    "86400",
    "86401",
    "360",
    "361",
    "6.3",
    "1e-4",
    "5126",
    "5125",
    "5123",
    "5121",
    "5120",
    "5122",
    "34962",
    "34963",
];

/// Strings the readers look for: glTF, VRM, tracking, mapping and session vocabulary.
const WORDS: &[&str] = &[
    "",
    "jawOpen",
    "JawOpen",
    "eyeBlinkLeft",
    "EyeBlink_L",
    "mouthSmile_R",
    "browInnerUp",
    "tongueOut",
    "blendShape1.jawOpen",
    "aa",
    "blink",
    "blinkLeft",
    "happy",
    "joy",
    "neutral",
    "lookUp",
    "vrm:happy",
    "custom",
    "head",
    "Head",
    "neck",
    "SCALAR",
    "VEC2",
    "VEC3",
    "VEC4",
    "MAT4",
    "POSITION",
    "NORMAL",
    "TEXCOORD_0",
    "JOINTS_0",
    "WEIGHTS_0",
    "image/png",
    "image/jpeg",
    "data:application/octet-stream;base64,AAAA",
    "data:image/png;base64,iVBORw0KGgo=",
    "KHR_materials_unlit",
    "KHR_draco_mesh_compression",
    "VRMC_vrm",
    "VRM",
    "block",
    "blend",
    "likeness-session",
    "00:00:00:00.000",
    "23:59:59:59.999",
    "24:00:00:00.000",
    "00:00:00:00.0001",
    "-01:00:00:00.000",
    "nan",
    "inf",
    "1/0",
    "30000/1001",
    "0/1",
    "1e308/1e-308",
    "inf/1",
    "25/1",
    "webcam:",
    "ffmpeg:lavfi:",
    "\u{feff}",
    "é",
];

/// Object keys worth adding where they are missing.
const KEYS: &[&str] = &[
    "accessors",
    "bufferViews",
    "buffers",
    "buffer",
    "byteOffset",
    "byteLength",
    "byteStride",
    "count",
    "componentType",
    "normalized",
    "sparse",
    "type",
    "min",
    "max",
    "meshes",
    "primitives",
    "attributes",
    "indices",
    "targets",
    "weights",
    "extras",
    "targetNames",
    "nodes",
    "children",
    "mesh",
    "skin",
    "skins",
    "joints",
    "inverseBindMatrices",
    "matrix",
    "rotation",
    "scale",
    "translation",
    "scene",
    "scenes",
    "materials",
    "textures",
    "images",
    "samplers",
    "source",
    "uri",
    "mimeType",
    "extensions",
    "extensionsUsed",
    "extensionsRequired",
    "expressions",
    "preset",
    "morphTargetBinds",
    "node",
    "index",
    "weight",
    "isBinary",
    "overrideBlink",
    "humanoid",
    "humanBones",
    "blendShapeMaster",
    "blendShapeGroups",
    "binds",
    "presetName",
    "arkit_names",
    "blendshape_names",
    "frames",
    "time_s",
    "face",
    "arkit_weights",
    "rotation_deg",
    "landmarks_68",
    "camera",
    "fps",
    "version",
    "channels",
    "gain",
    "offset",
    "clamp",
    "curve",
    "invert",
    "neutral",
    "head",
    "mirror",
    "enabled",
    "format",
    "info",
    "tracks",
    "observations",
    "detected",
    "crop",
    "dtype",
    "shape",
    "data_offsets",
    "__metadata__",
    "streams",
    "width",
    "height",
    "avg_frame_rate",
    "r_frame_rate",
    "nb_frames",
];

/// libFuzzer's custom mutator: half the time `default` (libFuzzer's own mutation), else
/// one edit of this module on `data[..size]`, written back in place when it fits in
/// `max_size`. Returns the new size.
pub fn libfuzzer_mutate(
    format: Format,
    data: &mut [u8],
    size: usize,
    max_size: usize,
    seed: u32,
    default: impl FnOnce(&mut [u8], usize, usize) -> usize,
) -> usize {
    let mut rng = Rng::new((u64::from(seed) << 32) | 0x5eed);
    if rng.chance(2) {
        return default(data, size, max_size);
    }
    let size = size.min(data.len());
    let out = mutate_once(&data[..size], &[], format, &mut rng);
    let room = max_size.min(data.len());
    if out.len() > room {
        return default(data, size, max_size);
    }
    data[..out.len()].copy_from_slice(&out);
    out.len()
}

/// A libFuzzer dictionary of the words, keys and numbers the structural edits use.
pub fn dictionary() -> String {
    let quoted = |token: &str| {
        let mut out = String::from("\"");
        for b in token.bytes() {
            match b {
                b'"' | b'\\' => out.push_str(&format!("\\x{b:02x}")),
                0x20..=0x7e => out.push(b as char),
                _ => out.push_str(&format!("\\x{b:02x}")),
            }
        }
        out.push('"');
        out
    };
    let mut lines =
        vec!["# Generated by `cargo run -p likeness-fuzzing --example make_corpus`.".to_owned()];
    lines.extend(KEYS.iter().map(|k| quoted(&format!("\"{k}\":"))));
    lines.extend(
        WORDS
            .iter()
            .filter(|w| !w.is_empty())
            .map(|w| quoted(&format!("\"{w}\""))),
    );
    lines.extend(NUMBERS.iter().map(|n| quoted(n)));
    lines.join("\n") + "\n"
}

/// `seed` mutated 1 to 4 times; `other` is another seed for splicing.
pub fn mutate(seed: &[u8], other: &[u8], format: Format, rng: &mut Rng) -> Vec<u8> {
    let mut data = seed.to_vec();
    for _ in 0..1 + rng.below(4) {
        data = mutate_once(&data, other, format, rng);
    }
    data
}

fn mutate_once(data: &[u8], other: &[u8], format: Format, rng: &mut Rng) -> Vec<u8> {
    // Half the time a structural edit where the format has one.
    if rng.chance(2) {
        let edited = match format {
            Format::Binary => None,
            Format::Json => json_text(data, rng),
            Format::Csv => csv(data, rng),
            Format::Gltf => gltf(data, rng),
            Format::Safetensors => safetensors(data, rng),
            Format::Video => video(data, rng),
        };
        if let Some(edited) = edited {
            return edited;
        }
    }
    bytes(data, other, rng)
}

/// One edit of the raw bytes.
pub fn bytes(data: &[u8], other: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut out = data.to_vec();
    let len = out.len();
    match rng.below(10) {
        0 if len > 0 => {
            let i = rng.below(len);
            out[i] ^= 1 << rng.below(8);
        }
        1 if len > 0 => {
            let i = rng.below(len);
            out[i] = *rng.pick(&[0, 1, 0x7f, 0x80, 0xff, b'0', b'9', b'"', b',', b'\n', b'{']);
        }
        2 if len >= 4 => {
            let i = rng.below(len - 3);
            let v: u32 = *rng.pick(&[
                0,
                1,
                0xff,
                0xffff,
                0x7fff_ffff,
                0x8000_0000,
                0xffff_ffff,
                len as u32,
                (len as u32).wrapping_mul(2),
            ]);
            out[i..i + 4].copy_from_slice(&v.to_le_bytes());
        }
        3 => out.truncate(rng.below(len + 1)),
        4 if len > 0 => {
            let start = rng.below(len);
            let end = (start + 1 + rng.below(16.min(len - start))).min(len);
            out.drain(start..end);
        }
        5 => {
            let at = rng.below(len + 1);
            let n = 1 + rng.below(8);
            let inserted: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
            out.splice(at..at, inserted);
        }
        6 if len > 0 => {
            // Duplicate a range (repeated records, chunks).
            let start = rng.below(len);
            let end = (start + 1 + rng.below(64)).min(len);
            let piece = out[start..end].to_vec();
            let at = rng.below(len + 1);
            out.splice(at..at, piece);
        }
        7 if !other.is_empty() => {
            // Splice: our start, the other seed's end.
            let cut = rng.below(len + 1);
            let from = rng.below(other.len());
            out.truncate(cut);
            out.extend_from_slice(&other[from..]);
        }
        8 if len > 1 => {
            // Copy a range over another place.
            let start = rng.below(len);
            let end = (start + 1 + rng.below(32)).min(len);
            let piece = out[start..end].to_vec();
            let at = rng.below(len);
            for (k, b) in piece.into_iter().enumerate() {
                if let Some(slot) = out.get_mut(at + k) {
                    *slot = b;
                }
            }
        }
        _ => {
            // Replace a run of ASCII digits by an interesting number.
            if let Some(edited) = replace_number_token(&out, rng) {
                return edited;
            }
            if len > 0 {
                let i = rng.below(len);
                out[i] = out[i].wrapping_add(1 + rng.below(3) as u8);
            }
        }
    }
    out
}

fn replace_number_token(data: &[u8], rng: &mut Rng) -> Option<Vec<u8>> {
    let starts: Vec<usize> = (0..data.len())
        .filter(|&i| data[i].is_ascii_digit() && (i == 0 || !data[i - 1].is_ascii_alphanumeric()))
        .collect();
    if starts.is_empty() {
        return None;
    }
    let start = *rng.pick(&starts);
    let end = (start..data.len())
        .find(|&i| !matches!(data[i], b'0'..=b'9' | b'.' | b'e' | b'E' | b'-' | b'+'))
        .unwrap_or(data.len());
    let mut out = data[..start].to_vec();
    out.extend_from_slice(rng.pick(NUMBERS).as_bytes());
    out.extend_from_slice(&data[end..]);
    Some(out)
}

/// A random value: an interesting number, a word, or another type altogether.
fn interesting_value(rng: &mut Rng) -> Value {
    match rng.below(6) {
        0 | 1 => serde_json::from_str(rng.pick::<&str>(NUMBERS)).unwrap_or(Value::Null),
        2 => Value::String((*rng.pick(WORDS)).to_owned()),
        3 => json!([]),
        4 => json!({}),
        _ => match rng.below(3) {
            0 => Value::Null,
            1 => Value::Bool(true),
            _ => Value::Bool(false),
        },
    }
}

/// A step from a JSON value to one of its children.
#[derive(Clone, Debug)]
enum Step {
    Index(usize),
    Key(String),
}

fn count_nodes(v: &Value) -> usize {
    1 + match v {
        Value::Array(a) => a.iter().map(count_nodes).sum(),
        Value::Object(o) => o.values().map(count_nodes).sum(),
        _ => 0,
    }
}

/// The path to the `n`-th node of a depth-first walk.
fn path_of(v: &Value, n: &mut usize, path: &mut Vec<Step>) -> bool {
    if *n == 0 {
        return true;
    }
    *n -= 1;
    match v {
        Value::Array(a) => a.iter().enumerate().any(|(i, c)| {
            path.push(Step::Index(i));
            let found = path_of(c, n, path);
            if !found {
                path.pop();
            }
            found
        }),
        Value::Object(o) => o.iter().any(|(k, c)| {
            path.push(Step::Key(k.clone()));
            let found = path_of(c, n, path);
            if !found {
                path.pop();
            }
            found
        }),
        _ => false,
    }
}

fn at<'a>(v: &'a Value, path: &[Step]) -> Option<&'a Value> {
    path.iter().try_fold(v, |v, s| match s {
        Step::Index(i) => v.get(*i),
        Step::Key(k) => v.get(k),
    })
}

fn at_mut<'a>(v: &'a mut Value, path: &[Step]) -> Option<&'a mut Value> {
    path.iter().try_fold(v, |v, s| match s {
        Step::Index(i) => v.get_mut(*i),
        Step::Key(k) => v.get_mut(k),
    })
}

fn random_path(root: &Value, rng: &mut Rng) -> Vec<Step> {
    let mut n = rng.below(count_nodes(root));
    let mut path = Vec::new();
    path_of(root, &mut n, &mut path);
    path
}

/// One structural edit of a JSON value: a node replaced (by an interesting value, a
/// nearby number, or a copy of another node), removed, duplicated, or given a new key.
/// `false` if nothing changed.
pub fn json_value(root: &mut Value, rng: &mut Rng) -> bool {
    let before = root.clone();
    let donor = at(root, &random_path(root, rng)).cloned();
    let path = random_path(root, rng);
    let Some(node) = at_mut(root, &path) else {
        return false;
    };
    match rng.below(8) {
        0 | 1 => *node = interesting_value(rng),
        2 => {
            if let Some(d) = donor {
                *node = d;
            }
        }
        3 => match node {
            Value::Number(x) => {
                let v = x.as_f64().unwrap_or(0.0);
                let nearby = *rng.pick(&[v + 1.0, v - 1.0, v * 2.0, -v, v / 2.0, v + 0.5]);
                *node = json!(nearby);
            }
            Value::String(text) => match rng.below(3) {
                0 => text.push_str(rng.pick::<&str>(WORDS)),
                1 => {
                    let keep = rng.below(text.chars().count() + 1);
                    *text = text.chars().take(keep).collect();
                }
                _ => *text = (*rng.pick(WORDS)).to_owned(),
            },
            _ => *node = interesting_value(rng),
        },
        4 => match node {
            // Duplicate an element (arrays that are meant to be aligned stop being so).
            Value::Array(a) if !a.is_empty() => {
                let i = rng.below(a.len());
                let copies = if rng.chance(8) { 1 + rng.below(64) } else { 1 };
                for _ in 0..copies {
                    a.insert(i, a[i].clone());
                }
            }
            Value::Object(o) => {
                let value = match donor {
                    Some(d) if rng.chance(2) => d,
                    _ => interesting_value(rng),
                };
                o.insert((*rng.pick(KEYS)).to_owned(), value);
            }
            _ => *node = json!([node.clone(), node.clone()]),
        },
        _ => {
            // Remove the node from its parent.
            let Some((last, parent_path)) = path.split_last() else {
                *node = interesting_value(rng);
                return *root != before;
            };
            match (at_mut(root, parent_path), last) {
                (Some(Value::Array(a)), Step::Index(i)) => {
                    a.remove(*i);
                }
                (Some(Value::Object(o)), Step::Key(k)) => {
                    o.remove(k);
                }
                _ => {}
            }
        }
    }
    *root != before
}

/// A JSON text edited structurally (re-serialised compact or pretty).
fn json_text(data: &[u8], rng: &mut Rng) -> Option<Vec<u8>> {
    let mut value: Value = serde_json::from_slice(data).ok()?;
    if !json_value(&mut value, rng) {
        return None;
    }
    Some(to_json_bytes(&value, rng))
}

fn to_json_bytes(value: &Value, rng: &mut Rng) -> Vec<u8> {
    let text = if rng.chance(2) {
        serde_json::to_vec(value)
    } else {
        serde_json::to_vec_pretty(value)
    };
    text.unwrap_or_default()
}

fn csv(data: &[u8], rng: &mut Rng) -> Option<Vec<u8>> {
    let text = std::str::from_utf8(data).ok()?;
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    if lines.is_empty() {
        return None;
    }
    let i = rng.below(lines.len());
    match rng.below(5) {
        0 => {
            let line = lines[i].clone();
            lines.insert(rng.below(lines.len() + 1), line);
        }
        1 if lines.len() > 1 => {
            lines.remove(i);
        }
        2 => {
            let j = rng.below(lines.len());
            lines.swap(i, j);
        }
        _ => {
            let mut cells: Vec<String> = lines[i].split(',').map(str::to_owned).collect();
            let c = rng.below(cells.len());
            match rng.below(4) {
                0 if cells.len() > 1 => {
                    cells.remove(c);
                }
                1 => cells.insert(c, (*rng.pick(NUMBERS)).to_owned()),
                2 => cells[c] = (*rng.pick(WORDS)).to_owned(),
                _ => cells[c] = (*rng.pick(NUMBERS)).to_owned(),
            }
            lines[i] = cells.join(",");
        }
    }
    let mut out = lines.join("\n");
    if rng.chance(2) {
        out.push('\n');
    }
    Some(out.into_bytes())
}

/// A GLB's parts: JSON chunk and binary chunk (if any).
pub(crate) fn split_glb(data: &[u8]) -> Option<(Vec<u8>, Option<Vec<u8>>)> {
    let u32_at = |i: usize| -> Option<usize> {
        Some(u32::from_le_bytes(data.get(i..i + 4)?.try_into().ok()?) as usize)
    };
    if !data.starts_with(b"glTF") {
        return None;
    }
    let json_len = u32_at(12)?;
    let json = data.get(20..20 + json_len)?.to_vec();
    let bin_at = 20 + json_len;
    let bin = u32_at(bin_at).and_then(|n| data.get(bin_at + 8..bin_at + 8 + n).map(<[u8]>::to_vec));
    Some((json, bin))
}

/// A GLB from a JSON chunk and a binary chunk, lengths and padding as the format wants.
pub fn join_glb(json: &[u8], bin: Option<&[u8]>) -> Vec<u8> {
    let mut json = json.to_vec();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut bin = bin.map(<[u8]>::to_vec);
    if let Some(b) = &mut bin {
        while !b.len().is_multiple_of(4) {
            b.push(0);
        }
    }
    let total = 12 + 8 + json.len() + bin.as_ref().map_or(0, |b| 8 + b.len());
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    if let Some(b) = bin {
        out.extend_from_slice(&(b.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&b);
    }
    out
}

fn gltf(data: &[u8], rng: &mut Rng) -> Option<Vec<u8>> {
    let Some((json, bin)) = split_glb(data) else {
        // A .gltf: its JSON.
        return json_text(data, rng);
    };
    if bin.is_some() && rng.chance(4) {
        let bin = bin.unwrap_or_default();
        let edited = bytes(&bin, &[], rng);
        return Some(join_glb(&json, Some(&edited)));
    }
    let mut value: Value = serde_json::from_slice(&json).ok()?;
    if !json_value(&mut value, rng) {
        return None;
    }
    let json = serde_json::to_vec(&value).ok()?;
    Some(join_glb(&json, bin.as_deref()))
}

/// A safetensors file's header (JSON) and data.
fn split_safetensors(data: &[u8]) -> Option<(Value, &[u8])> {
    let n = u64::from_le_bytes(data.get(..8)?.try_into().ok()?) as usize;
    let header = data.get(8..8usize.checked_add(n)?)?;
    Some((serde_json::from_slice(header).ok()?, &data[8 + n..]))
}

pub fn join_safetensors(header: &Value, data: &[u8]) -> Vec<u8> {
    let mut text = serde_json::to_vec(header).unwrap_or_default();
    while !text.len().is_multiple_of(8) {
        text.push(b' ');
    }
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(&text);
    out.extend_from_slice(data);
    out
}

fn safetensors(data: &[u8], rng: &mut Rng) -> Option<Vec<u8>> {
    let (mut header, body) = split_safetensors(data)?;
    match rng.below(4) {
        // The JSON inside a metadata string (tracks, info, observations).
        0 | 1 => {
            let meta = header.get_mut("__metadata__")?.as_object_mut()?;
            let keys: Vec<String> = meta.keys().cloned().collect();
            if keys.is_empty() {
                return None;
            }
            let key = rng.pick(&keys).clone();
            let text = meta.get(&key)?.as_str()?.to_owned();
            let mut inner: Value = match serde_json::from_str(&text) {
                Ok(v) => v,
                Err(_) => {
                    meta.insert(key, Value::String((*rng.pick(WORDS)).to_owned()));
                    return Some(join_safetensors(&header, body));
                }
            };
            if !json_value(&mut inner, rng) {
                return None;
            }
            let text = String::from_utf8(to_json_bytes(&inner, rng)).ok()?;
            meta.insert(key, Value::String(text));
            Some(join_safetensors(&header, body))
        }
        // The header itself (tensor names, shapes, offsets, metadata strings).
        2 => {
            if !json_value(&mut header, rng) {
                return None;
            }
            Some(join_safetensors(&header, body))
        }
        // The tensor data.
        _ => Some(join_safetensors(&header, &bytes(body, &[], rng))),
    }
}

fn video(data: &[u8], rng: &mut Rng) -> Option<Vec<u8>> {
    let (&mode, rest) = data.split_first()?;
    let edited = match mode % 5 {
        0 => json_text(rest, rng)?,
        1 | 3 | 4 => csv(rest, rng)?,
        _ => return None,
    };
    let mut out = vec![mode];
    out.extend_from_slice(&edited);
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Map;

    #[test]
    fn the_same_seed_gives_the_same_case_and_cases_differ() {
        let seed = br#"{"a": [1, 2, {"b": "jawOpen"}], "c": 0.5}"#;
        let run = |s: u64| {
            let mut rng = Rng::new(s);
            mutate(seed, b"other", Format::Json, &mut rng)
        };
        assert_eq!(run(7), run(7));
        let distinct: std::collections::HashSet<Vec<u8>> = (0..200).map(run).collect();
        assert!(distinct.len() > 150, "{} distinct cases", distinct.len());
    }

    #[test]
    fn json_edits_keep_the_text_json() {
        let seed = br#"{"a": [1, 2, {"b": "jawOpen"}], "c": 0.5, "d": {"e": null}}"#;
        let mut rng = Rng::new(1);
        let mut edited = 0;
        for _ in 0..500 {
            if let Some(out) = json_text(seed, &mut rng) {
                assert!(serde_json::from_slice::<Value>(&out).is_ok());
                if out != seed {
                    edited += 1;
                }
            }
        }
        assert!(edited > 400, "{edited} of 500 edited");
    }

    #[test]
    fn glb_and_safetensors_edits_keep_the_containers_readable() {
        let glb = join_glb(
            br#"{"asset":{"version":"2.0"},"x":[1,2,3]}"#,
            Some(&[1, 2, 3, 4]),
        );
        let mut meta = Map::new();
        meta.insert("tracks".into(), json!(r#"{"frames": [1, 2]}"#));
        let st = join_safetensors(&json!({"__metadata__": meta}), &[]);
        let mut rng = Rng::new(3);
        let (mut glb_edits, mut st_edits) = (0, 0);
        for _ in 0..300 {
            if let Some(out) = gltf(&glb, &mut rng) {
                let (json, _) = split_glb(&out).expect("still a GLB");
                assert!(serde_json::from_slice::<Value>(&json).is_ok());
                glb_edits += 1;
            }
            if let Some(out) = safetensors(&st, &mut rng) {
                assert!(split_safetensors(&out).is_some(), "still safetensors");
                st_edits += 1;
            }
        }
        assert!(
            glb_edits > 200 && st_edits > 200,
            "{glb_edits} and {st_edits} edits"
        );
    }
}
