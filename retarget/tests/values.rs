//! Absurd values are refused, naming the line or frame and the field (Live Link Face CSV
//! here, tracking JSON in `src/tracks.rs`), and the worst tracks that are accepted still
//! export glTF animations the Khronos validator passes.

mod common;

use common::{temp_dir, validate};
use face::names::{NUM_ARKIT, arkit_index};
use retarget::export::{
    live_link_csv, live_link_header, parse_live_link_csv, retarget_clip, write_animation_glb,
};
use retarget::{MappingData, Puppet, Retargeter, Tracks};

/// A Live Link CSV with these timecodes; `values(k)` gives line k's 61 values.
fn csv(timecodes: &[&str], values: impl Fn(usize) -> Vec<String>) -> String {
    let mut text = live_link_header();
    text.push('\n');
    for (k, tc) in timecodes.iter().enumerate() {
        let mut row = vec![tc.to_string(), "61".to_string()];
        row.extend(values(k));
        text.push_str(&row.join(","));
        text.push('\n');
    }
    text
}

fn zeros(_: usize) -> Vec<String> {
    vec!["0".to_string(); 61]
}

fn assert_refused(text: &str, expect: &[&str]) {
    let err = match parse_live_link_csv(text) {
        Ok(t) => panic!("accepted ({} frames): {text}", t.frames.len()),
        Err(e) => e,
    };
    for e in expect {
        assert!(err.contains(e), "`{err}` lacks `{e}`");
    }
}

#[test]
fn live_link_timecodes_must_be_numbers_that_increase_within_24_hours() {
    let ok = csv(&["00:10:00:00.000", "00:10:00:01.000"], zeros);
    let t = parse_live_link_csv(&ok).unwrap();
    assert_eq!(t.frames.len(), 2);
    assert!((t.frames[1].time_s - t.frames[0].time_s - 1.0 / 60.0).abs() < 1e-3);
    // The header is line 1: the second data row is line 3.
    for (codes, expect) in [
        (
            ["00:00:01:00.000", "00:00:01:NaN"],
            &["line 3", "NaN", "not a finite number"][..],
        ),
        (
            ["00:00:01:00.000", "00:00:01:inf"],
            &["line 3", "inf", "not a finite number"],
        ),
        (["00:00:01:00.000", "later"], &["line 3", "`later`"]),
        (
            ["00:00:01:00.000", "00:-1:01:00.000"],
            &["line 3", "minutes", "`-1`"],
        ),
        (
            ["00:00:01:00.000", "00:00:61:00.000"],
            &["line 3", "61 seconds"],
        ),
        (
            ["00:00:01:00.000", "00:00:01:75.000"],
            &["line 3", "75 frames"],
        ),
        // Backwards (the issue's "-0.30 s" clip) and duplicate.
        (
            ["00:00:01:00.000", "00:00:00:42.000"],
            &["line 3", "before line 2", "increase"],
        ),
        (
            ["00:00:01:00.000", "00:00:01:00.000"],
            &["line 3", "the same as line 2"],
        ),
        // Beyond 24 h, and beyond f32's range.
        (["00:00:01:00.000", "25:00:00:00.000"], &["line 3", "24 h"]),
        (
            ["00:00:01:00.000", "999999999:00:00:00.000"],
            &["line 3", "24 h"],
        ),
    ] {
        assert_refused(&csv(&codes, zeros), expect);
    }
    // Two timecodes 1 ms apart at 18 h are one 32-bit float.
    assert_refused(
        &csv(&["18:00:00:00.000", "18:00:00:00.030"], zeros),
        &["line 2 and line 3", "32-bit"],
    );
}

#[test]
fn live_link_values_are_held_to_the_tracks_rules() {
    let jaw = retarget::names::live_link_name(arkit_index("jawOpen").unwrap());
    let jaw_col = live_link_header()
        .split(',')
        .position(|h| h == jaw)
        .unwrap()
        - 2;
    let head_pitch = NUM_ARKIT + 1;
    let with = |col: usize, v: &'static str| {
        move |k: usize| {
            let mut row = zeros(k);
            if k == 1 {
                row[col] = v.to_string();
            }
            row
        }
    };
    let codes = ["00:00:01:00.000", "00:00:01:01.000"];
    for (values, expect) in [
        (
            csv(&codes, with(jaw_col, "1e300")),
            &["line 3", "`JawOpen`", "1e300"][..],
        ),
        (
            csv(&codes, with(jaw_col, "NaN")),
            &["line 3", "`JawOpen`", "not a finite number"],
        ),
        (
            csv(&codes, with(jaw_col, "-2")),
            &["line 3", "`JawOpen`", "-2"],
        ),
        (
            csv(&codes, with(jaw_col, "wide")),
            &["line 3", "`JawOpen`", "`wide`"],
        ),
        (
            csv(&codes, with(head_pitch, "7")),
            &["line 3", "`HeadPitch`", "radians"],
        ),
        (
            csv(&codes, with(head_pitch, "-inf")),
            &["line 3", "`HeadPitch`", "not a finite number"],
        ),
    ] {
        assert_refused(&values, expect);
    }
    // Overshoots within the bounds are clamped; the angle bound is 2 pi either way.
    let t = parse_live_link_csv(&csv(&codes, |k| {
        let mut row = zeros(k);
        row[jaw_col] = ["1.5", "-0.5"][k].to_string();
        row[head_pitch] = ["6.28", "-6.28"][k].to_string();
        row
    }))
    .unwrap();
    let a = arkit_index("jawOpen").unwrap();
    assert_eq!([t.frames[0].arkit[a], t.frames[1].arkit[a]], [1.0, 0.0]);
    assert!((t.frames[0].rotation_deg.unwrap()[1] - 359.817).abs() < 1e-2);
    // A header without blendshape columns, and a short row.
    assert_refused("Timecode,Foo\n00:00:00:00.000,1\n", &["blendshape column"]);
    assert_refused(
        &format!("{}\n00:00:00:00.000,61,0.5\n", live_link_header()),
        &["line 2", "3 cells"],
    );
}

/// The worst tracks the parser accepts: the last 1/128 s of 24 h, weights at both clamp
/// edges and beyond them, and the largest head angles.
fn worst_tracks_json(frames: usize) -> String {
    let all = [
        r#"{"time_s": 86399.984375, "arkit_weights": [1.5, -0.5], "rotation_deg": [360, -360, 359.9]}"#,
        r#"{"time_s": 86399.9921875, "arkit_weights": [-0.5, 1.5], "rotation_deg": [-360, 360, -359.9]}"#,
        r#"{"time_s": 86400, "arkit_weights": [1.0, 0.0], "rotation_deg": [0.0, 0.0, 0.0]}"#,
    ];
    format!(
        r#"{{"arkit_names": ["jawOpen", "eyeBlinkLeft"], "frames": [{}]}}"#,
        all[all.len() - frames..].join(",")
    )
}

#[test]
fn the_worst_accepted_tracks_export_valid_gltf() {
    let dir = temp_dir("values");
    let style = &retarget::generator::styles()[0];
    let path = dir.join(format!("{}.glb", style.name));
    std::fs::write(&path, retarget::generator::glb_bytes(style).unwrap()).unwrap();
    let puppet = Puppet::load(&path).unwrap();
    let r = Retargeter::new(&puppet, &MappingData::default());
    let mut cases: Vec<(String, Tracks)> = (1..=3)
        .map(|n| {
            let t = Tracks::parse(&worst_tracks_json(n)).unwrap();
            assert_eq!(t.frames.len(), n);
            (format!("json-{n}"), t)
        })
        .collect();
    // The same through a Live Link CSV, written and read back (timecodes near 24:00:00).
    let csv_text = live_link_csv(&r, &cases[2].1);
    let from_csv = parse_live_link_csv(&csv_text).unwrap_or_else(|e| panic!("{e}\n{csv_text}"));
    assert_eq!(from_csv.frames.len(), 3);
    cases.push(("csv-3".into(), from_csv));
    // A clip that starts at 0 and has frames 1/10,000 s apart (the smallest step).
    cases.push((
        "fast".into(),
        Tracks::parse(
            r#"{"arkit_names": ["jawOpen"], "frames": [
                {"time_s": 0, "arkit_weights": [0]},
                {"time_s": 0.0001, "arkit_weights": [1]},
                {"time_s": 0.0002, "arkit_weights": [0.5]}]}"#,
        )
        .unwrap(),
    ));
    for (name, tracks) in &cases {
        tracks.check().unwrap_or_else(|e| panic!("{name}: {e}"));
        let clip = retarget_clip(&r, tracks);
        let out = dir.join(format!("{name}.glb"));
        write_animation_glb(&puppet, &r, &clip, &out).unwrap_or_else(|e| panic!("{name}: {e}"));
        validate(&out);
    }
    // The weights were clamped at the edges.
    let jaw = arkit_index("jawOpen").unwrap();
    let first = &cases[2].1.frames;
    assert_eq!([first[0].arkit[jaw], first[1].arkit[jaw]], [1.0, 0.0]);
}
