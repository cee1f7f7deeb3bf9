//! Exports of retargeted motion: the puppet as GLB with a glTF animation (morph weights and
//! head rotation, timestamps from the footage), Live Link Face CSV, and JSON.
//!
//! The GLB export keeps the whole source file: its JSON is edited as JSON (so VRM and other
//! extensions, extras and existing animations survive), every buffer is packed into the one
//! binary chunk, external images are embedded, and one animation named `likeness` is
//! appended.

use std::path::Path;

use face::names::{ARKIT_NAMES, NUM_ARKIT};
use serde_json::{Value, json};

use crate::driver::{PuppetPose, Retargeter};
use crate::error::{Result, RetargetError, io_error};
use crate::glb::GlbBuilder;
use crate::names::live_link_name;
use crate::puppet::{
    ImageSource, LazyFolder, Puppet, decode_image, image_bytes, image_source, load_buffers,
    split_gltf,
};
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
    Ok(files::write_atomically(out, &data)?)
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
    let bad = |reason: String| RetargetError::InvalidPuppet {
        path: source.clone(),
        reason,
    };
    let mut raw = split_gltf(bytes, source)?.json;
    let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| bad(format!("invalid glTF: {e}")))?;
    let folder = LazyFolder::new(base);
    let buffers = load_buffers(&gltf.document, &folder, gltf.blob).map_err(bad)?;
    // What an external image becomes: its decoded-and-checked bytes, or nothing.
    let images = raw
        .get("images")
        .and_then(Value::as_array)
        .cloned()
        .unwrap_or_default();
    let referenced = referenced_images(&raw);
    let mut embedded: Vec<Option<Vec<u8>>> = Vec::with_capacity(images.len());
    for (k, image) in images.iter().enumerate() {
        let what = format!("image {k}");
        let Ok(ImageSource::File(uri)) = image_source(image) else {
            embedded.push(None); // in the file already (buffer view or data URI)
            continue;
        };
        // A file beside the puppet travels only if a texture shows it and it is an image.
        let bytes = if referenced.contains(&k) {
            image_bytes(&ImageSource::File(uri), &raw, &buffers, &folder, &what).and_then(|b| {
                decode_image(&b)
                    .map(|_| b)
                    .map_err(|e| format!("{what}: {e}"))
            })
        } else {
            Err(format!("{what} (`{uri}`) is not used by any texture"))
        };
        embedded.push(Some(bytes.unwrap_or_else(|reason| {
            tracing::warn!(
                "{}: {reason}; the export carries a 1x1 white image in its place",
                source.display()
            );
            placeholder_png()
        })));
    }

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
    if let Some(list) = raw.get_mut("buffers").and_then(Value::as_array_mut) {
        list.clear();
    }
    // Exporting an exported file replaces its animation instead of adding a second one.
    if let Some(list) = raw.get_mut("animations").and_then(Value::as_array_mut) {
        list.retain(|a| a.get("name").and_then(Value::as_str) != Some(ANIMATION_NAME));
    }
    let mut doc = GlbBuilder::new(raw, bin);
    // External images move into the binary chunk (their files would not travel with the GLB).
    for (k, data) in embedded.into_iter().enumerate() {
        let Some(data) = data else { continue };
        let mime = if data.starts_with(b"\x89PNG") {
            "image/png"
        } else {
            "image/jpeg"
        };
        let view = doc.view(&data, None);
        let image = &mut doc.json["images"][k];
        if let Some(obj) = image.as_object_mut() {
            obj.remove("uri");
        }
        image["bufferView"] = json!(view);
        image["mimeType"] = json!(mime);
    }

    // The animation: one sampler input shared by every channel. Files were checked when
    // read (`Tracks::parse`); tracks made in code are checked here, as glTF requires
    // finite, strictly increasing times.
    let times: Vec<f32> = clip.iter().map(|f| f.time_s - clip[0].time_s).collect();
    if let Some(k) = (0..times.len()).find(|&k| {
        !times[k].is_finite() || !clip[k].time_s.is_finite() || (k > 0 && times[k] <= times[k - 1])
    }) {
        return Err(write_err(
            out,
            format!(
                "frame {k} of the clip has time {} s, not a finite time after the frame before; glTF animations need increasing times",
                clip[k].time_s
            ),
        ));
    }
    let finite_pose = |f: &ClipFrame| {
        f.pose.morph_weights.iter().flatten().all(|w| w.is_finite())
            && f.pose.head.is_none_or(|(_, q)| q.is_finite())
    };
    if let Some(k) = clip.iter().position(|f| !finite_pose(f)) {
        return Err(write_err(
            out,
            format!("frame {k} of the clip has a weight or head rotation that is not finite"),
        ));
    }
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

/// Images a texture shows (its `source` or an extension's, e.g. `KHR_texture_basisu`), or
/// that the VRM extension names (thumbnails).
fn referenced_images(json: &Value) -> Vec<usize> {
    let mut found = Vec::new();
    let textures = json.get("textures").and_then(Value::as_array);
    for texture in textures.into_iter().flatten() {
        found.extend(texture.get("source").and_then(Value::as_u64));
        let extensions = texture.get("extensions").and_then(Value::as_object);
        for ext in extensions.into_iter().flat_map(|e| e.values()) {
            found.extend(ext.get("source").and_then(Value::as_u64));
        }
    }
    let extensions = json.get("extensions");
    found.extend(
        extensions
            .and_then(|e| e.pointer("/VRMC_vrm/meta/thumbnailImage"))
            .and_then(Value::as_u64),
    );
    // VRM 0.x names a texture for its thumbnail.
    if let Some(t) = extensions
        .and_then(|e| e.pointer("/VRM/meta/texture"))
        .and_then(Value::as_u64)
        && let Some(source) = json
            .pointer(&format!("/textures/{t}/source"))
            .and_then(Value::as_u64)
    {
        found.push(source);
    }
    found.into_iter().map(|i| i as usize).collect()
}

/// A 1x1 white PNG, what an image that may not travel becomes (the JSON keeps its index, so
/// nothing that refers to images needs renumbering).
fn placeholder_png() -> Vec<u8> {
    let mut bytes = Vec::new();
    let pixel = image::RgbaImage::from_pixel(1, 1, image::Rgba([255, 255, 255, 255]));
    // Encoding one pixel into memory cannot fail.
    let _ = pixel.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    );
    bytes
}

// --- Live Link Face CSV ----------------------------------------------------------------

/// Largest eye rotation the eyeLook weights stand for, in degrees: the gaze the studio
/// draws and the training data shows (`face::gaze`).
pub const EYE_YAW_RANGE_DEG: f32 = face::gaze::GAZE_YAW_DEG_PER_UNIT;
pub const EYE_PITCH_RANGE_DEG: f32 = face::gaze::GAZE_PITCH_DEG_PER_UNIT;
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
/// weights: the gaze the studio draws ([`face::gaze::eye_angles`]; the eyeLook channels are
/// the same in ARKit and ICT).
pub fn eye_angles_rad(arkit: &[f32; NUM_ARKIT]) -> [f32; 4] {
    let [[left_yaw, left_pitch], [right_yaw, right_pitch]] =
        face::gaze::eye_angles(&face::names::arkit_to_ict(arkit));
    [left_yaw, left_pitch, right_yaw, right_pitch]
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
/// and for using LLF recordings as tracks. Values are held to the rules of tracking JSON
/// (`tracks` module): blendshape columns within [-0.5, 1.5] (clamped to [0, 1]), head
/// angles within ±2π rad, timecodes `HH:MM:SS:FF.fff` (frames at [`LIVE_LINK_FPS`])
/// increasing within 24 h. Errors name the line (the header is line 1) and the column.
pub fn parse_live_link_csv(text: &str) -> std::result::Result<Tracks, String> {
    use crate::tracks::{TimeChecker, checked_angle_rad, checked_weight};
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
    if shape_cols.iter().all(Option::is_none) {
        return Err(
            "the header has no blendshape column (EyeBlinkLeft, ..., TongueOut): not a Live \
             Link Face CSV"
                .into(),
        );
    }
    let head_cols = [col("HeadYaw"), col("HeadPitch"), col("HeadRoll")];
    let mut tracks = Tracks::default();
    let mut times = TimeChecker::new();
    for (k, line) in lines.enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let line_no = k + 2;
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        let cell = |c: usize| -> std::result::Result<&str, String> {
            cells.get(c).copied().ok_or_else(|| {
                format!(
                    "line {line_no}: {} cells, so no column {} (`{}`)",
                    cells.len(),
                    c + 1,
                    header[c]
                )
            })
        };
        let number = |c: usize| -> std::result::Result<f64, String> {
            let text = cell(c)?;
            text.parse().map_err(|_| {
                format!(
                    "line {line_no}, column `{}`: `{text}` is not a number",
                    header[c]
                )
            })
        };
        let mut arkit = [0.0; NUM_ARKIT];
        for (a, c) in shape_cols.iter().enumerate() {
            if let Some(c) = *c {
                arkit[a] = checked_weight(number(c)?)
                    .map_err(|e| format!("line {line_no}, column `{}`: {e}", header[c]))?;
            }
        }
        let rotation_deg = match head_cols {
            [Some(yaw), Some(pitch), Some(roll)] => {
                let mut deg = [0.0; 3];
                for (slot, c) in deg.iter_mut().zip([yaw, pitch, roll]) {
                    *slot = checked_angle_rad(number(c)?)
                        .map_err(|e| format!("line {line_no}, column `{}`: {e}", header[c]))?;
                }
                Some(deg)
            }
            _ => None,
        };
        let stamp = cell(time_col)?;
        let t =
            parse_timecode(stamp).map_err(|e| format!("line {line_no}: Timecode `{stamp}` {e}"))?;
        let time_s = times.check(
            &format!("line {line_no}"),
            &format!("Timecode `{stamp}`"),
            t,
        )?;
        tracks.frames.push(crate::tracks::TrackedFrame {
            time_s,
            arkit,
            rotation_deg,
        });
    }
    Ok(tracks)
}

/// `HH:MM:SS:FF.fff` (frames at [`LIVE_LINK_FPS`]) in seconds, or what is wrong with it.
/// Hours are not limited here: the tracks' 24 h bound refuses a time beyond it.
fn parse_timecode(text: &str) -> std::result::Result<f64, String> {
    let parts: Vec<&str> = text.split(':').collect();
    let [h, m, s, f] = parts.as_slice() else {
        return Err("is not HH:MM:SS:FF.fff".into());
    };
    let whole = |part: &str, what: &str, below: u32| -> std::result::Result<f64, String> {
        let digits =
            !part.is_empty() && part.len() <= 9 && part.bytes().all(|b| b.is_ascii_digit());
        match part.parse::<u32>() {
            Ok(v) if digits && v < below => Ok(f64::from(v)),
            Ok(v) if digits => Err(format!("has {v} {what} (at most {})", below - 1)),
            _ => Err(format!("has `{part}` for {what}, not a whole number")),
        }
    };
    let secs = whole(h, "hours", u32::MAX)? * 3600.0
        + whole(m, "minutes", 60)? * 60.0
        + whole(s, "seconds", 60)?;
    let frames: f64 = f
        .parse()
        .map_err(|_| format!("has `{f}` for frames, not a number"))?;
    let fps = f64::from(LIVE_LINK_FPS);
    if !frames.is_finite() {
        return Err(format!("has `{f}` for frames, not a finite number"));
    }
    if !(0.0..fps).contains(&frames) {
        return Err(format!("has {frames} frames (from 0 to under {fps})"));
    }
    Ok(secs + frames / fps)
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
