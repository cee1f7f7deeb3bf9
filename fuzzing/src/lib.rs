//! # likeness-fuzzing: every input from outside, fed malformed data
//!
//! Owns the fuzz targets of Likeness: one `pub fn <target>(data: &[u8])` per kind of file
//! or stream that enters from outside (puppets, tracking JSON, Live Link CSV, mapping
//! files, session files, images, the video reader's parsing). Each calls the project's own
//! entry points for that input and asserts what must hold for any bytes: no panic, and for
//! what loads, cheap invariants (values in range, round trips through the project's own
//! writers). It also owns a small deterministic mutator ([`mutate`]) and the seed corpus
//! generator ([`seeds`]).
//!
//! Two drivers call the same functions: `fuzz/` (cargo-fuzz and libFuzzer on nightly,
//! `scripts/fuzz.sh`) for long runs, and `tests/never_panics.rs` (stable, in CI) for
//! thousands of mutated cases of the committed seed corpus.
//!
//! It must not change what it tests: it only calls public entry points, reads no file
//! outside the corpus and writes nothing (the seed generator writes where it is told).
//! Its targets panic on purpose when an invariant breaks: a panic is how a fuzzer reports.

pub mod mutate;
pub mod seeds;
mod targets;

use std::cell::RefCell;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Once;

pub use targets::{image, live_link_csv, mapping, puppet, session, tracks_json, video};

/// The fuzz targets, by the name of their cargo-fuzz binary and corpus folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Target {
    /// GLB, glTF and VRM puppets: load, retarget, pose, export as GLB and read it back.
    Puppet,
    /// Tracking JSON: `retarget::Tracks::parse` and `tracking::record::TracksDocument`.
    TracksJson,
    /// Live Link Face CSV (`retarget::export::parse_live_link_csv`).
    LiveLinkCsv,
    /// Mapping sidecars (`hero.mapping.json`).
    Mapping,
    /// `.likeness` session files (`tracking::session`, the studio's `StudioSession`).
    Session,
    /// Image decoding with the tracker's limits (`tracking::source::decode_image`).
    Image,
    /// The video reader's parsing: `ffprobe` output, live input sizes, raw RGB frames,
    /// input names and the order of an image folder.
    Video,
}

impl Target {
    pub const ALL: [Target; 7] = [
        Target::Puppet,
        Target::TracksJson,
        Target::LiveLinkCsv,
        Target::Mapping,
        Target::Session,
        Target::Image,
        Target::Video,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Target::Puppet => "puppet",
            Target::TracksJson => "tracks_json",
            Target::LiveLinkCsv => "live_link_csv",
            Target::Mapping => "mapping",
            Target::Session => "session",
            Target::Image => "image",
            Target::Video => "video",
        }
    }

    pub fn from_name(name: &str) -> Option<Target> {
        Target::ALL.into_iter().find(|t| t.name() == name)
    }

    /// Runs the target on one input (panics on a failure, like under libFuzzer).
    pub fn run(self, data: &[u8]) {
        match self {
            Target::Puppet => puppet(data),
            Target::TracksJson => tracks_json(data),
            Target::LiveLinkCsv => live_link_csv(data),
            Target::Mapping => mapping(data),
            Target::Session => session(data),
            Target::Image => image(data),
            Target::Video => video(data),
        }
    }

    /// What the mutator knows of the inputs' structure.
    pub fn format(self) -> mutate::Format {
        match self {
            Target::Puppet => mutate::Format::Gltf,
            Target::TracksJson | Target::Mapping => mutate::Format::Json,
            Target::LiveLinkCsv => mutate::Format::Csv,
            Target::Session => mutate::Format::Safetensors,
            Target::Image => mutate::Format::Binary,
            Target::Video => mutate::Format::Video,
        }
    }
}

thread_local! {
    /// The panics of the case running on this thread (`None`: no case is running).
    static PANICS: RefCell<Option<Vec<String>>> = const { RefCell::new(None) };
}

/// Runs `target` on `data` and reports every panic on this thread during the call, also
/// one the code under test catches itself (the puppet loader turns a panic of the glTF
/// reader into an error; libFuzzer aborts on it before it is caught, and so does this).
pub fn run_case(target: Target, data: &[u8]) -> Result<(), String> {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let in_case = PANICS
                .try_with(|p| {
                    let mut p = p.borrow_mut();
                    let Some(list) = p.as_mut() else {
                        return false;
                    };
                    let payload = info.payload();
                    let message = payload
                        .downcast_ref::<&str>()
                        .map(|s| (*s).to_owned())
                        .or_else(|| payload.downcast_ref::<String>().cloned())
                        .unwrap_or_default();
                    let at = info
                        .location()
                        .map(|l| format!("{}:{}", l.file(), l.line()))
                        .unwrap_or_default();
                    list.push(format!("panicked at {at}: {message}"));
                    true
                })
                .unwrap_or(false);
            if !in_case {
                previous(info);
            }
        }));
    });
    PANICS.with(|p| *p.borrow_mut() = Some(Vec::new()));
    let result = catch_unwind(AssertUnwindSafe(|| target.run(data)));
    let panics = PANICS.with(|p| p.borrow_mut().take()).unwrap_or_default();
    match (result, panics.is_empty()) {
        (Ok(()), true) => Ok(()),
        (_, false) => Err(panics.join("\n")),
        (Err(_), true) => Err("panicked (no message)".into()),
    }
}
