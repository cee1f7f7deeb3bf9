//! The tracking crate's files are written by the project's one atomic writer: a failure to
//! write says "cannot write" (not "cannot read"), and a good write leaves no temporary.

use tracking::record::TracksDocument;

#[test]
fn a_write_failure_is_reported_as_a_write_and_a_write_leaves_no_temporary() {
    let dir = std::env::temp_dir().join(format!("likeness-tracking-writes-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let doc = TracksDocument::new("clip".into(), 30.0);

    let err = doc
        .save(&dir.join("missing/tracks.json"))
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("cannot write") && err.contains("does not exist"),
        "{err}"
    );
    // A folder where the file should be.
    std::fs::create_dir_all(dir.join("taken.json")).unwrap();
    let err = doc.save(&dir.join("taken.json")).unwrap_err().to_string();
    assert!(err.starts_with("cannot write"), "{err}");

    let out = dir.join("tracks.json");
    doc.save(&out).unwrap();
    assert_eq!(TracksDocument::load(&out).unwrap(), doc);
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.starts_with('.')), "{names:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
