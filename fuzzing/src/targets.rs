//! The targets: each takes any bytes, calls the project's entry points for one kind of
//! input, and panics (the fuzzers' signal) when something that must hold does not.

use std::io::Read;
use std::path::Path;
use std::sync::OnceLock;

use face::names::NUM_ARKIT;
use retarget::driver::PuppetPose;
use retarget::export::{
    animation_glb_bytes, clip_json, live_link_csv_raw, parse_live_link_csv, retarget_clip,
};
use retarget::tracks::TrackedFrame;
use retarget::{MappingData, Puppet, Retargeter, Tracks};
use tracking::record::TracksDocument;
use tracking::session::{Session, SessionParts};
use tracking::source::{
    InputSpec, RawFrame, RawFrames, check_frame_size, decode_image, natural_cmp, parse_live_size,
    parse_probe_output,
};

/// ARKit weights every loaded puppet is posed with: rest, half, full, alternating, and
/// values a caller may pass although no file holds them (out of range, NaN).
fn probes() -> Vec<[f32; NUM_ARKIT]> {
    vec![
        [0.0; NUM_ARKIT],
        [0.5; NUM_ARKIT],
        [1.0; NUM_ARKIT],
        std::array::from_fn(|a| (a % 2) as f32),
        std::array::from_fn(|a| match a % 4 {
            0 => -3.0,
            1 => 7.0,
            2 => f32::NAN,
            _ => f32::INFINITY,
        }),
    ]
}

/// Head rotations the probes come with (degrees): none, ordinary, extreme, not finite.
const ROTATIONS: [Option<[f32; 3]>; 4] = [
    None,
    Some([10.0, -5.0, 3.0]),
    Some([720.0, -400.0, 1e6]),
    Some([f32::NAN, 0.0, f32::INFINITY]),
];

/// What any pose must be: driven weights in [0, 1] (undriven ones keep the file's
/// defaults, so only finite), expression weights in [0, 1], a unit head rotation of a
/// node that exists.
fn check_pose(puppet: &Puppet, pose: &PuppetPose, defaults_in_unit_range: bool) {
    assert_eq!(
        pose.morph_weights.len(),
        puppet.meshes.len(),
        "one weight list per mesh"
    );
    for (m, (weights, mesh)) in pose.morph_weights.iter().zip(&puppet.meshes).enumerate() {
        assert_eq!(
            weights.len(),
            mesh.target_names.len(),
            "mesh {m}: one weight per morph target"
        );
        for (t, w) in weights.iter().enumerate() {
            assert!(w.is_finite(), "mesh {m} target {t}: weight {w}");
            if defaults_in_unit_range {
                assert!(
                    (0.0..=1.0).contains(w),
                    "mesh {m} target {t}: weight {w} outside [0, 1]"
                );
            }
        }
    }
    for (k, w) in pose.expression_weights.iter().enumerate() {
        assert!(
            (0.0..=1.0).contains(w),
            "VRM expression {k}: weight {w} outside [0, 1]"
        );
    }
    if let Some((node, q)) = pose.head {
        assert!(node < puppet.nodes.len(), "head node {node} does not exist");
        assert!(
            q.is_finite() && (q.length() - 1.0).abs() < 1e-3,
            "head rotation {q:?} is not a unit quaternion"
        );
    }
}

fn frame(time_s: f32, weight: f32, rotation_deg: Option<[f32; 3]>) -> TrackedFrame {
    TrackedFrame {
        time_s,
        arkit: [weight; NUM_ARKIT],
        rotation_deg,
    }
}

/// Puppets (GLB, glTF, VRM): a file loads or is an error; a loaded puppet is retargeted
/// and posed, and its animation export is a GLB that loads again with the same morph
/// targets. External files are not read (`base` is none).
pub fn puppet(data: &[u8]) {
    let Ok(puppet) = Puppet::from_slice(data, Path::new("fuzz.glb"), None) else {
        return;
    };
    assert_eq!(
        puppet.morph_targets().count(),
        puppet.morph_target_count(),
        "morph target count"
    );
    if let Some(h) = puppet.head_node(None) {
        assert!(h < puppet.nodes.len(), "head node {h} does not exist");
    }
    let defaults_in_unit_range = puppet
        .meshes
        .iter()
        .flat_map(|m| &m.default_weights)
        .all(|w| (0.0..=1.0).contains(w));
    let retargeter = Retargeter::new(&puppet, &MappingData::default());
    for arkit in probes() {
        for rotation in ROTATIONS {
            check_pose(
                &puppet,
                &retargeter.pose(&arkit, rotation),
                defaults_in_unit_range,
            );
        }
    }
    let _ = puppet.world_matrices(&[]);
    let tracks = Tracks {
        frames: vec![
            frame(0.0, 0.0, Some([0.0; 3])),
            frame(0.5, 1.0, Some([20.0, -10.0, 5.0])),
        ],
        ..Tracks::default()
    };
    let clip = retarget_clip(&retargeter, &tracks);
    let _ = clip_json(&puppet, &retargeter, &clip);
    let out = Path::new("fuzz-animation.glb");
    if let Ok(glb) = animation_glb_bytes(data, None, &puppet, &retargeter, &clip, out) {
        let again = Puppet::from_slice(&glb, out, None)
            .unwrap_or_else(|e| panic!("the animation export does not load again: {e}"));
        let names = |p: &Puppet| -> Vec<String> {
            p.morph_targets().map(|(_, _, n)| n.to_owned()).collect()
        };
        assert_eq!(
            names(&again),
            names(&puppet),
            "the animation export changed the morph targets"
        );
    }
}

/// What parsed tracks must be: weights in [0, 1], times finite, non-negative and
/// increasing, head angles finite.
fn check_tracks(tracks: &Tracks, what: &str) {
    let mut previous = None;
    for (k, f) in tracks.frames.iter().enumerate() {
        assert!(
            f.arkit.iter().all(|w| (0.0..=1.0).contains(w)),
            "{what}: frame {k} has a weight outside [0, 1]: {:?}",
            f.arkit
        );
        assert!(
            f.time_s.is_finite() && f.time_s >= 0.0,
            "{what}: frame {k} time {}",
            f.time_s
        );
        if let Some(p) = previous {
            assert!(
                f.time_s > p,
                "{what}: frame {k} time {} is not after {p}",
                f.time_s
            );
        }
        previous = Some(f.time_s);
        if let Some(r) = f.rotation_deg {
            assert!(
                r.iter().all(|v| v.is_finite()),
                "{what}: frame {k} rotation {r:?}"
            );
        }
    }
}

/// Tracking JSON, as the retargeter reads it (any third-party file with the few fields it
/// needs) and as the tracker's own document: parsed or refused; a document reads back
/// from its own JSON, equal.
pub fn tracks_json(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(tracks) = Tracks::parse(text) {
        check_tracks(&tracks, "tracking JSON");
    }
    if let Ok(doc) = TracksDocument::from_json(text) {
        let json = doc.to_json();
        let again = TracksDocument::from_json(&json)
            .unwrap_or_else(|e| panic!("a tracking document does not read back: {e}\n{json}"));
        assert!(again == doc, "a tracking document reads back different");
    }
}

/// Live Link Face CSV: parsed or refused; what parses is written back by the project's
/// own writer (`likeness track --csv`) and reads back with the same frames.
pub fn live_link_csv(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(tracks) = parse_live_link_csv(text) else {
        return;
    };
    check_tracks(&tracks, "Live Link CSV");
    let csv = live_link_csv_raw(&tracks);
    let again = parse_live_link_csv(&csv)
        .unwrap_or_else(|e| panic!("the CSV written from a parsed CSV does not read: {e}"));
    assert_eq!(
        again.frames.len(),
        tracks.frames.len(),
        "frames lost in a CSV round trip"
    );
    for (k, (a, b)) in again.frames.iter().zip(&tracks.frames).enumerate() {
        let close = |x: f32, y: f32, tolerance: f32| (x - y).abs() <= tolerance;
        assert!(
            a.arkit
                .iter()
                .zip(&b.arkit)
                .all(|(x, y)| close(*x, *y, 1e-5)),
            "frame {k}: weights changed in a CSV round trip"
        );
        // Timecodes resolve a thousandth of a 60 fps frame.
        assert!(
            close(a.time_s, b.time_s, 1e-4 + b.time_s * 1e-6),
            "frame {k}: time {} became {}",
            b.time_s,
            a.time_s
        );
    }
}

/// A tiny VRM 1.0 puppet with ARKit-named morph targets and VRM expressions, which the
/// mapping target drives.
fn mapping_puppet() -> &'static Puppet {
    static PUPPET: OnceLock<Puppet> = OnceLock::new();
    PUPPET.get_or_init(|| {
        let bytes = crate::seeds::vrm1_puppet();
        match Puppet::from_slice(&bytes, Path::new("mapping-fixture.vrm"), None) {
            Ok(p) => p,
            Err(e) => panic!("the mapping target's own puppet does not load: {e}"),
        }
    })
}

/// Mapping sidecars: parsed and validated as `MappingData::load` does (it reads from a
/// path only); a valid mapping saves to text that reads back equal, keeps poses in range
/// on a VRM puppet, and stays valid after a neutral calibration.
pub fn mapping(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz.mapping.json");
    let Ok(mapping) = serde_json::from_str::<MappingData>(text) else {
        return;
    };
    if mapping.validate(path).is_err() {
        return;
    }
    let saved = serde_json::to_string_pretty(&mapping)
        .unwrap_or_else(|e| panic!("a valid mapping does not serialise: {e}"));
    let again: MappingData = serde_json::from_str(&saved)
        .unwrap_or_else(|e| panic!("a saved mapping does not read back: {e}\n{saved}"));
    assert_eq!(again, mapping, "a mapping reads back different");
    let puppet = mapping_puppet();
    let retargeter = Retargeter::new(puppet, &mapping);
    for arkit in probes() {
        for rotation in ROTATIONS {
            check_pose(puppet, &retargeter.pose(&arkit, rotation), true);
        }
    }
    let mut calibrated = mapping.clone();
    calibrated.calibrate_neutral(&[0.25; NUM_ARKIT]);
    if let Err(e) = calibrated.validate(path) {
        panic!("a valid mapping is invalid after a neutral calibration: {e}");
    }
}

/// Session files: a file loads or is an error; a loaded one writes back to the same
/// session. Every check of the file's own data (metadata, tracking, observations,
/// footage) is reached without 21 MB of correction tensors through `SessionParts`, and
/// with the `studio` feature the studio's `StudioSession::from_file` checks them too.
pub fn session(data: &[u8]) {
    if let Ok(session) = Session::from_bytes(data) {
        let bytes = session
            .to_bytes()
            .unwrap_or_else(|e| panic!("a loaded session does not serialise: {e}"));
        let again = Session::from_bytes(&bytes)
            .unwrap_or_else(|e| panic!("a saved session does not load: {e}"));
        assert!(again == session, "a session reads back different");
    }
    let Ok(parts) = SessionParts::from_bytes(data) else {
        return;
    };
    let count = parts.tracks.frames.len();
    if let Some(frames) = &parts.footage {
        assert_eq!(frames.len(), count, "one footage frame per tracked frame");
    }
    assert!(
        parts.observations.is_empty() || parts.observations.len() == count,
        "observations for {count} frames: {}",
        parts.observations.len()
    );
    #[cfg(feature = "studio")]
    studio_session(parts);
}

/// The studio's reading of a session, with corrections of the wrong size: `from_file`
/// checks the file's own data first and the corrections last, so every case reaches all
/// the checks, and none may be accepted.
#[cfg(feature = "studio")]
fn studio_session(parts: SessionParts) {
    use face::uv::UvMap;
    let file = Session {
        info: parts.info,
        tracks: parts.tracks,
        footage: parts.footage,
        observations: parts.observations,
        corrections: face::PersonalCorrections {
            identity_shape: UvMap::zeros(1, 1, 3),
            expression_shapes: Vec::new(),
            static_albedo: UvMap::zeros(1, 1, 3),
            dynamic_albedo: Vec::new(),
        },
    };
    if likeness::studio_session::StudioSession::from_file(crate::seeds::tiny_face_model(), file)
        .is_ok()
    {
        panic!("the studio accepted a session with corrections of the wrong size");
    }
}

/// Image decoding as the tracker does it for image files, from bytes: decoded or
/// refused, never beyond the frame limits.
pub fn image(data: &[u8]) {
    if let Ok(image) = decode_image(data) {
        let (w, h) = image.dimensions();
        assert!(
            check_frame_size(w, h).is_ok(),
            "decoded a {w}x{h} image beyond the limits"
        );
    }
}

/// A reader that hands out its data in the pieces `sizes` says, with `Interrupted`
/// errors where a size is 0 (which a pipe may return).
struct Chunked<'a> {
    data: &'a [u8],
    sizes: &'a [u8],
    step: usize,
}

impl Read for Chunked<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.data.is_empty() || buf.is_empty() {
            return Ok(0);
        }
        let size = self.sizes.get(self.step % self.sizes.len().max(1)).copied();
        self.step += 1;
        let n = match size {
            Some(0) if self.step < 1000 => {
                return Err(std::io::ErrorKind::Interrupted.into());
            }
            Some(s) => usize::from(s).max(1),
            None => usize::MAX,
        };
        let n = n.min(buf.len()).min(self.data.len());
        buf[..n].copy_from_slice(&self.data[..n]);
        self.data = &self.data[n..];
        Ok(n)
    }
}

/// The video reader's parsing; the first byte chooses what the rest is: `ffprobe`'s JSON
/// about a video, `ffprobe`'s size of a live input, a raw RGB frame stream (then: width,
/// height, how many read sizes, the sizes, the stream), an input name, or a folder's file
/// names (one per line) to order.
pub fn video(data: &[u8]) {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    match mode % 5 {
        0 => probe_output(rest),
        1 => live_size(rest),
        2 => raw_frames(rest),
        3 => {
            let _ = InputSpec::parse(&String::from_utf8_lossy(rest));
        }
        _ => folder_order(rest),
    }
}

fn probe_output(stdout: &[u8]) {
    let Ok(info) = parse_probe_output(stdout) else {
        return;
    };
    assert!(
        check_frame_size(info.width, info.height).is_ok(),
        "accepted a {}x{} video",
        info.width,
        info.height
    );
    assert!(
        info.fps.is_finite() && info.fps > 0.0,
        "frame rate {}",
        info.fps
    );
    // The numbers are ffprobe's, unchanged.
    let stream = serde_json::from_slice::<serde_json::Value>(stdout)
        .ok()
        .and_then(|j| j.get("streams")?.get(0).cloned());
    if let Some(stream) = stream {
        for (key, value) in [("width", info.width), ("height", info.height)] {
            assert_eq!(
                stream.get(key).and_then(serde_json::Value::as_u64),
                Some(u64::from(value)),
                "{key} read as {value}"
            );
        }
    }
}

fn live_size(stdout: &[u8]) {
    let text = String::from_utf8_lossy(stdout);
    if let Some((w, h)) = parse_live_size(&text) {
        let first = text.trim().lines().next().unwrap_or("");
        assert!(
            first.contains(&w.to_string()) && first.contains(&h.to_string()),
            "size {w}x{h} is not in `{first}`"
        );
    }
}

fn raw_frames(rest: &[u8]) {
    let [w, h, n, rest @ ..] = rest else {
        return;
    };
    let (sizes, stream) = rest.split_at(usize::from(*n).min(rest.len()));
    let (w, h) = (u32::from(*w % 16) + 1, u32::from(*h % 16) + 1);
    let reader = Chunked {
        data: stream,
        sizes,
        step: 0,
    };
    let Ok(mut frames) = RawFrames::new(reader, w, h) else {
        panic!("{w}x{h} frames refused");
    };
    let len = (w * h * 3) as usize;
    let mut read = 0;
    loop {
        match frames.next_frame() {
            Ok(RawFrame::Frame(image)) => {
                assert_eq!(image.dimensions(), (w, h), "frame size");
                assert_eq!(
                    image.as_raw().as_slice(),
                    &stream[read * len..(read + 1) * len],
                    "frame {read} is not the stream's bytes"
                );
                read += 1;
            }
            Ok(RawFrame::End) => break,
            Err(e) => panic!("reading from memory failed: {e}"),
        }
    }
    assert_eq!(read, stream.len() / len, "whole frames read");
}

fn folder_order(rest: &[u8]) {
    let text = String::from_utf8_lossy(rest);
    let mut names: Vec<&str> = text.lines().take(64).collect();
    // Antisymmetry on pairs and transitivity on triples of the first few names (the cost
    // grows with the cube), then the sort of them all, which panics on an inconsistent
    // order.
    let few = &names[..names.len().min(10)];
    for a in few {
        for b in few {
            assert_eq!(
                natural_cmp(a, b),
                natural_cmp(b, a).reverse(),
                "`{a}` and `{b}` compare both ways differently"
            );
            if natural_cmp(a, b).is_gt() {
                continue;
            }
            for c in few {
                if natural_cmp(b, c).is_le() {
                    assert!(
                        natural_cmp(a, c).is_le(),
                        "`{a}` <= `{b}` <= `{c}` but not `{a}` <= `{c}`"
                    );
                }
            }
        }
    }
    names.sort_by(|a, b| natural_cmp(a, b));
    assert!(names.windows(2).all(|p| natural_cmp(p[0], p[1]).is_le()));
}
