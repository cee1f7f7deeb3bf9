//! Every fuzz target, on stable: its seed corpus (`fuzz/corpus/<target>/`), the inputs of
//! crashes found before (`fuzz/regressions/<target>/`), and thousands of deterministic
//! mutations of the seeds. A failing case prints its seed; it is written to
//! `target/likeness-fuzzing/<target>-<seed>.bin` and runs alone with
//! `LIKENESS_FUZZ_CASE=<target>:<seed> cargo test -p likeness-fuzzing --test never_panics`
//! (or under libFuzzer: `cargo +nightly fuzz run <target> <file>` from the repository).
//! `LIKENESS_FUZZ_CASES=N` runs N mutated cases per target instead of the default.

use std::path::{Path, PathBuf};

use likeness_fuzzing::mutate::{Rng, mutate};
use likeness_fuzzing::{Target, run_case};

fn repo() -> PathBuf {
    let fuzzing = Path::new(env!("CARGO_MANIFEST_DIR"));
    fuzzing.parent().unwrap_or(fuzzing).to_path_buf()
}

/// The files of `dir` (sorted by name, so cases are the same everywhere).
fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut list: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    list.retain(|p| p.is_file());
    list.sort();
    list.into_iter()
        .map(|p| {
            let bytes = std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            (p, bytes)
        })
        .collect()
}

/// Case `index` of `target`: a seed chosen and mutated by a generator seeded with `seed`.
fn case_seed(target: Target, index: u64) -> u64 {
    let name_hash = target
        .name()
        .bytes()
        .fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
        });
    name_hash ^ index
}

fn make_case(seeds: &[(PathBuf, Vec<u8>)], target: Target, seed: u64) -> Vec<u8> {
    let mut rng = Rng::new(seed);
    let a = &seeds[rng.below(seeds.len())].1;
    let b = &seeds[rng.below(seeds.len())].1;
    mutate(a, b, target.format(), &mut rng)
}

fn save_failure(target: Target, seed: u64, input: &[u8]) -> PathBuf {
    let dir = repo().join("target/likeness-fuzzing");
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join(format!("{}-{seed}.bin", target.name()));
    let _ = std::fs::write(&path, input);
    path
}

/// The regressions of `target` listed in `fuzz/regressions/open.txt` (file names); each
/// must exist.
fn open_regressions(target: Target) -> Vec<String> {
    let list =
        std::fs::read_to_string(repo().join("fuzz/regressions/open.txt")).unwrap_or_default();
    let prefix = format!("{}/", target.name());
    let open: Vec<String> = list
        .lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| l.split_whitespace().next()?.strip_prefix(&prefix))
        .map(str::to_owned)
        .collect();
    for name in &open {
        let path = repo()
            .join("fuzz/regressions")
            .join(target.name())
            .join(name);
        assert!(
            path.is_file(),
            "fuzz/regressions/open.txt lists {}, which does not exist",
            path.display()
        );
    }
    open
}

fn check(target: Target, default_cases: u64) {
    let corpus = files(&repo().join("fuzz/corpus").join(target.name()));
    assert!(
        corpus.len() >= 2,
        "fuzz/corpus/{} has {} seeds (cargo run -p likeness-fuzzing --example make_corpus)",
        target.name(),
        corpus.len()
    );
    let mut failures = Vec::new();
    let regressions = files(&repo().join("fuzz/regressions").join(target.name()));
    let open = open_regressions(target);
    for (path, bytes) in corpus.iter().chain(&regressions) {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
        let result = run_case(target, bytes);
        if name.as_ref().is_some_and(|n| open.contains(n)) {
            // Handed over, not fixed yet: reported, not failed.
            match result {
                Ok(()) => eprintln!(
                    "{}: passes now; remove it from fuzz/regressions/open.txt",
                    path.display()
                ),
                Err(e) => eprintln!("{} (open): {e}", path.display()),
            }
        } else if let Err(e) = result {
            failures.push(format!("{}: {e}", path.display()));
        }
    }
    let only = std::env::var("LIKENESS_FUZZ_CASE").ok();
    let seeds: Vec<u64> = match only.as_deref().and_then(|c| c.split_once(':')) {
        Some((name, seed)) if name == target.name() => {
            vec![seed.parse().expect("LIKENESS_FUZZ_CASE=<target>:<seed>")]
        }
        Some(_) => Vec::new(),
        None => {
            let cases = std::env::var("LIKENESS_FUZZ_CASES")
                .ok()
                .and_then(|n| n.parse().ok())
                .unwrap_or(default_cases);
            (0..cases).map(|i| case_seed(target, i)).collect()
        }
    };
    for seed in &seeds {
        let input = make_case(&corpus, target, *seed);
        if let Err(e) = run_case(target, &input) {
            let path = save_failure(target, *seed, &input);
            failures.push(format!(
                "case seed {seed} ({} bytes, saved to {}; rerun with LIKENESS_FUZZ_CASE={}:{seed}): {e}",
                input.len(),
                path.display(),
                target.name()
            ));
        }
        if failures.len() >= 10 {
            break;
        }
    }
    assert!(
        failures.is_empty(),
        "{}: {} failing input(s) ({} seeds, {} regressions, {} mutated cases):\n{}",
        target.name(),
        failures.len(),
        corpus.len(),
        regressions.len(),
        seeds.len(),
        failures.join("\n\n")
    );
}

#[test]
fn puppet() {
    check(Target::Puppet, 8000);
}

#[test]
fn tracks_json() {
    check(Target::TracksJson, 10_000);
}

#[test]
fn live_link_csv() {
    check(Target::LiveLinkCsv, 10_000);
}

#[test]
fn mapping() {
    check(Target::Mapping, 10_000);
}

#[test]
fn session() {
    check(Target::Session, 10_000);
}

#[test]
fn image() {
    check(Target::Image, 10_000);
}

#[test]
fn video() {
    check(Target::Video, 10_000);
}
