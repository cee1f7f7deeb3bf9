//! Exports of retargeted motion: the puppet as GLB with a glTF animation (morph weights and
//! head rotation, timestamps from the footage), Live Link Face CSV, and JSON.
//!
//! The GLB export keeps the whole source file: its JSON is edited as JSON (so VRM and other
//! extensions, extras and existing animations survive), every buffer is packed into the one
//! binary chunk, external images are embedded, and one animation named `likeness` is
//! appended.

use std::path::Path;

use face::names::{ARKIT_NAMES, NUM_ARKIT, arkit_index};
use serde_json::{Value, json};

use crate::driver::{PuppetPose, Retargeter};
use crate::error::{Result, RetargetError, io_error};
use crate::glb::GlbBuilder;
use crate::mapping::write_atomically;
use crate::names::live_link_name;
use crate::puppet::{Puppet, split_gltf};
use crate::tracks::Tracks;

/// One retargeted frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ClipFrame {
    pub time_s: f32,
    pub pose: PuppetPose,
}

/// Runs the retargeter over every tracked frame.
pub fn retarget_clip(retargeter: &Retargeter, tracks: &Tracks) -> Vec<ClipFrame> {
    tracks
        .frames
        .iter()
        .map(|f| ClipFrame {
            time_s: f.time_s,
            pose: retargeter.pose(&f.arkit, f.rotation_deg),
        })
        .collect()
}

/// Name of the animation the GLB export appends.
pub const ANIMATION_NAME: &str = "likeness";

fn write_err(path: &Path, reason: impl Into<String>) -> RetargetError {
    RetargetError::Write {
        path: path.to_owned(),
        reason: reason.into(),
    }
}

/// Writes `puppet` (re-read from its file) with the clip as a glTF animation, as GLB.
pub fn write_animation_glb(
    puppet: &Puppet,
    retargeter: &Retargeter,
    clip: &[ClipFrame],
    out: &Path,
) -> Result<()> {
    if clip.is_empty() {
        return Err(write_err(out, "the clip has no frames with a face"));
    }
    let source = &puppet.path;
    let bytes = std::fs::read(source).map_err(io_error(source))?;
    let data = animation_glb_bytes(&bytes, source.parent(), puppet, retargeter, clip, out)?;
    write_atomically(out, &data)
}

/// [`write_animation_glb`]'s file as bytes, from the puppet file's `bytes` (what a browser
/// has); `base` is where its external buffers and images are (`None`: embedded data only)
/// and `out` names the result in messages.
pub fn animation_glb_bytes(
    bytes: &[u8],
    base: Option<&Path>,
    puppet: &Puppet,
    retargeter: &Retargeter,
    clip: &[ClipFrame],
    out: &Path,
) -> Result<Vec<u8>> {
    if clip.is_empty() {
        return Err(write_err(out, "the clip has no frames with a face"));
    }
    let source = &puppet.path;
    let mut raw = split_gltf(bytes, source)?.json;
    let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| RetargetError::InvalidPuppet {
        path: source.clone(),
        reason: format!("invalid glTF: {e}"),
    })?;
    let buffers = gltf::import_buffers(&gltf.document, base, gltf.blob).map_err(|e| {
        RetargetError::InvalidPuppet {
            path: source.clone(),
            reason: format!("cannot read its buffers: {e}"),
        }
    })?;

    // Pack every buffer into one, 4-byte aligned.
    let mut bin: Vec<u8> = Vec::new();
    let mut buffer_offsets = Vec::with_capacity(buffers.len());
    for data in &buffers {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        buffer_offsets.push(bin.len());
        bin.extend_from_slice(data);
    }
    let views = raw.get_mut("bufferViews").and_then(Value::as_array_mut);
    for view in views.into_iter().flatten() {
        let b = view.get("buffer").and_then(Value::as_u64).unwrap_or(0) as usize;
        let offset = view.get("byteOffset").and_then(Value::as_u64).unwrap_or(0) as usize;
        let base_offset = *buffer_offsets
            .get(b)
            .ok_or_else(|| write_err(out, format!("a buffer view refers to missing buffer {b}")))?;
        view["buffer"] = json!(0);
        view["byteOffset"] = json!(base_offset + offset);
    }
    let mut doc = GlbBuilder::new(raw, bin);
    // External images move into the binary chunk (their files would not travel with the GLB).
    let image_count = doc
        .json
        .get("images")
        .and_then(Value::as_array)
        .map_or(0, Vec::len);
    for k in 0..image_count {
        let Some(uri) = doc.json["images"][k]
            .get("uri")
            .and_then(Value::as_str)
            .map(str::to_owned)
        else {
            continue;
        };
        if uri.starts_with("data:") {
            continue; // valid in a GLB as it is
        }
        let Some(dir) = base else { continue };
        let file = dir.join(percent_decode(&uri));
        let data = std::fs::read(&file).map_err(io_error(&file))?;
        let mime = match file
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("png") => "image/png",
            Some("jpg" | "jpeg") => "image/jpeg",
            Some("webp") => "image/webp",
            Some("ktx2") => "image/ktx2",
            _ => "application/octet-stream",
        };
        let view = doc.view(&data, None);
        let image = &mut doc.json["images"][k];
        if let Some(obj) = image.as_object_mut() {
            obj.remove("uri");
        }
        image["bufferView"] = json!(view);
        image["mimeType"] = json!(mime);
    }

    // The animation: one sampler input shared by every channel.
    let times: Vec<f32> = clip.iter().map(|f| f.time_s - clip[0].time_s).collect();
    let input = doc.float_accessor(&times, "SCALAR", None, true);
    let mut samplers = Vec::new();
    let mut channels = Vec::new();
    for (node_index, node) in puppet.nodes.iter().enumerate() {
        let Some(m) = node.mesh.filter(|&m| retargeter.drives_mesh(m)) else {
            continue;
        };
        let values: Vec<f32> = clip
            .iter()
            .flat_map(|f| f.pose.morph_weights[m].iter().copied())
            .collect();
        let output = doc.float_accessor(&values, "SCALAR", None, false);
        channels.push(
            json!({"sampler": samplers.len(), "target": {"node": node_index, "path": "weights"}}),
        );
        samplers.push(json!({"input": input, "output": output, "interpolation": "LINEAR"}));
    }
    if let Some(head) = retargeter
        .head_node()
        .filter(|_| clip.iter().any(|f| f.pose.head.is_some()))
    {
        let rest = puppet.nodes[head].rotation;
        let quats: Vec<f32> = clip
            .iter()
            .flat_map(|f| f.pose.head.map_or(rest, |(_, q)| q).to_array())
            .collect();
        let output = doc.float_accessor(&quats, "VEC4", None, false);
        channels
            .push(json!({"sampler": samplers.len(), "target": {"node": head, "path": "rotation"}}));
        samplers.push(json!({"input": input, "output": output, "interpolation": "LINEAR"}));
    }
    if channels.is_empty() {
        return Err(write_err(
            out,
            "nothing to animate: the mapping drives no morph target and there is no head rotation",
        ));
    }
    doc.push(
        "animations",
        json!({"name": ANIMATION_NAME, "samplers": samplers, "channels": channels}),
    );
    doc.finish().map_err(|e| write_err(out, e))
}

/// `%20` -> space in relative URIs (glTF URIs are percent-encoded).
fn percent_decode(uri: &str) -> String {
    let bytes = uri.as_bytes();
    let hex = |b: u8| (b as char).to_digit(16);
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%'
            && i + 2 < bytes.len()
            && let (Some(hi), Some(lo)) = (hex(bytes[i + 1]), hex(bytes[i + 2]))
        {
            out.push((hi * 16 + lo) as u8);
            i += 3;
            continue;
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

// --- Live Link Face CSV ----------------------------------------------------------------

/// Largest eye rotation the eyeLook weights stand for, in degrees (ARKit's gaze shapes
/// reach about this far).
pub const EYE_YAW_RANGE_DEG: f32 = 30.0;
pub const EYE_PITCH_RANGE_DEG: f32 = 25.0;
/// Live Link Face timecodes count frames at this rate.
pub const LIVE_LINK_FPS: f32 = 60.0;
/// Value columns after `Timecode` and `BlendShapeCount`: 52 shapes, head and eyes.
pub const LIVE_LINK_VALUE_COLUMNS: usize = NUM_ARKIT + 9;

/// The header: `Timecode,BlendShapeCount,EyeBlinkLeft,...,TongueOut,HeadYaw,HeadPitch,
/// HeadRoll,LeftEyeYaw,LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll`.
pub fn live_link_header() -> String {
    let mut cols = vec!["Timecode".to_owned(), "BlendShapeCount".to_owned()];
    cols.extend((0..NUM_ARKIT).map(live_link_name));
    cols.extend(
        [
            "HeadYaw",
            "HeadPitch",
            "HeadRoll",
            "LeftEyeYaw",
            "LeftEyePitch",
            "LeftEyeRoll",
            "RightEyeYaw",
            "RightEyePitch",
            "RightEyeRoll",
        ]
        .map(str::to_owned),
    );
    cols.join(",")
}

/// `HH:MM:SS:FF.fff` at [`LIVE_LINK_FPS`], as Live Link Face writes it.
pub fn live_link_timecode(time_s: f32) -> String {
    let t = f64::from(time_s.max(0.0));
    let whole = t.floor();
    let h = (whole / 3600.0).floor();
    let m = ((whole - h * 3600.0) / 60.0).floor();
    let s = whole - h * 3600.0 - m * 60.0;
    let frames = (t - whole) * f64::from(LIVE_LINK_FPS);
    let frame = frames.floor();
    let sub = ((frames - frame) * 1000.0).round().min(999.0);
    format!("{h:02}:{m:02}:{s:02}:{frame:02}.{sub:03}")
}

/// Eye angles `[left yaw, left pitch, right yaw, right pitch]` in radians from the eyeLook
/// weights: yaw = (look towards the performer's left) x 30 degrees, pitch = (down - up) x
/// 25 degrees, the same signs as head yaw and pitch (`face::camera`).
pub fn eye_angles_rad(arkit: &[f32; NUM_ARKIT]) -> [f32; 4] {
    let w = |n: &str| arkit_index(n).map_or(0.0, |a| arkit[a]);
    let yaw = EYE_YAW_RANGE_DEG.to_radians();
    let pitch = EYE_PITCH_RANGE_DEG.to_radians();
    [
        (w("eyeLookOutLeft") - w("eyeLookInLeft")) * yaw,
        (w("eyeLookDownLeft") - w("eyeLookUpLeft")) * pitch,
        (w("eyeLookInRight") - w("eyeLookOutRight")) * yaw,
        (w("eyeLookDownRight") - w("eyeLookUpRight")) * pitch,
    ]
}

/// Live Link Face CSV of the tracked ARKit weights after the mapping's neutral calibration,
/// with head and eye angles in radians.
pub fn live_link_csv(retargeter: &Retargeter, tracks: &Tracks) -> String {
    live_link_csv_with(tracks, |arkit| retargeter.calibrated(arkit))
}

/// Live Link Face CSV of the tracked ARKit weights as they are (no puppet, no
/// calibration): what `likeness track --csv` writes.
pub fn live_link_csv_raw(tracks: &Tracks) -> String {
    live_link_csv_with(tracks, |arkit| *arkit)
}

fn live_link_csv_with(
    tracks: &Tracks,
    calibrate: impl Fn(&[f32; NUM_ARKIT]) -> [f32; NUM_ARKIT],
) -> String {
    let mut out = live_link_header();
    out.push('\n');
    for f in &tracks.frames {
        let calibrated = calibrate(&f.arkit);
        let [yaw, pitch, roll] = f.rotation_deg.unwrap_or([0.0; 3]).map(f32::to_radians);
        let [ly, lp, ry, rp] = eye_angles_rad(&calibrated);
        let mut row = vec![
            live_link_timecode(f.time_s),
            LIVE_LINK_VALUE_COLUMNS.to_string(),
        ];
        row.extend(calibrated.iter().map(|v| format!("{v:.6}")));
        row.extend(
            [yaw, pitch, roll, ly, lp, 0.0, ry, rp, 0.0]
                .iter()
                .map(|v| format!("{v:.6}")),
        );
        out.push_str(&row.join(","));
        out.push('\n');
    }
    out
}

/// Reads a Live Link Face CSV back into ARKit weights and head angles (degrees), for tests
/// and for using LLF recordings as tracks.
pub fn parse_live_link_csv(text: &str) -> std::result::Result<Tracks, String> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .ok_or("empty CSV")?
        .split(',')
        .map(str::trim)
        .collect();
    let col = |name: &str| header.iter().position(|h| h.eq_ignore_ascii_case(name));
    let time_col = col("Timecode").ok_or("no Timecode column")?;
    let shape_cols: Vec<Option<usize>> = (0..NUM_ARKIT).map(|a| col(&live_link_name(a))).collect();
    let head_cols = [col("HeadYaw"), col("HeadPitch"), col("HeadRoll")];
    let mut tracks = Tracks::default();
    for (k, line) in lines.enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        let number = |c: usize| -> std::result::Result<f32, String> {
            let v: f32 = cells
                .get(c)
                .ok_or(format!("row {k}: too few columns"))?
                .parse()
                .map_err(|e| format!("row {k} column {c}: {e}"))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(format!("row {k} column {c}: not finite"))
            }
        };
        let mut arkit = [0.0; NUM_ARKIT];
        for (a, c) in shape_cols.iter().enumerate() {
            if let Some(c) = c {
                arkit[a] = number(*c)?.clamp(0.0, 1.0);
            }
        }
        let rotation_deg = if head_cols.iter().all(Option::is_some) {
            let mut r = [0.0; 3];
            for (slot, c) in r.iter_mut().zip(head_cols) {
                *slot = number(c.unwrap_or_default())?.to_degrees();
            }
            Some(r)
        } else {
            None
        };
        let time_s = parse_timecode(cells.get(time_col).ok_or(format!("row {k}: no timecode"))?)
            .ok_or(format!("row {k}: bad timecode"))?;
        tracks.frames.push(crate::tracks::TrackedFrame {
            time_s,
            arkit,
            rotation_deg,
        });
    }
    Ok(tracks)
}

fn parse_timecode(text: &str) -> Option<f32> {
    let parts: Vec<&str> = text.split(':').collect();
    let [h, m, s, f] = parts.as_slice() else {
        return None;
    };
    let frames: f64 = f.parse().ok()?;
    let secs =
        h.parse::<f64>().ok()? * 3600.0 + m.parse::<f64>().ok()? * 60.0 + s.parse::<f64>().ok()?;
    Some((secs + frames / f64::from(LIVE_LINK_FPS)) as f32)
}

// --- JSON ------------------------------------------------------------------------------

/// The retargeted clip as JSON: the target list once, then per frame the weights aligned
/// with it and the head node's local rotation quaternion `[x, y, z, w]`.
pub fn clip_json(puppet: &Puppet, retargeter: &Retargeter, clip: &[ClipFrame]) -> Value {
    let targets: Vec<Value> = puppet
        .morph_targets()
        .map(|(m, _, n)| json!({"mesh": puppet.meshes[m].name, "name": n}))
        .collect();
    let frames: Vec<Value> = clip
        .iter()
        .map(|f| {
            let weights: Vec<f32> = f.pose.morph_weights.iter().flatten().copied().collect();
            json!({"time_s": f.time_s, "weights": weights, "head_rotation": f.pose.head.map(|(_, q)| q.to_array())})
        })
        .collect();
    json!({
        "format": "likeness-retarget",
        "version": 1,
        "puppet": puppet.path.file_name().map(|n| n.to_string_lossy().into_owned()),
        "targets": targets,
        "head_node": retargeter.head_node().map(|h| puppet.nodes[h].name.clone()),
        "arkit_names": ARKIT_NAMES.to_vec(),
        "frames": frames,
    })
}
