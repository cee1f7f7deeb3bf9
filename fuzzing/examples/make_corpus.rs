//! Writes the seed corpus and the dictionary: `cargo run -p likeness-fuzzing --example
//! make_corpus [-- DIR]` (default `fuzz/corpus/`, one folder per target; files of the same
//! name are replaced, others left alone; the dictionary goes beside it as
//! `likeness.dict`). The video seeds made by FFmpeg need `ffmpeg` and `ffprobe`.

use std::path::PathBuf;

use likeness_fuzzing::{Target, seeds};

fn main() -> std::io::Result<()> {
    let root = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus"));
    for target in Target::ALL {
        let dir = root.join(target.name());
        std::fs::create_dir_all(&dir)?;
        let mut total = 0;
        let list = seeds::generate(target);
        for (name, bytes) in &list {
            std::fs::write(dir.join(name), bytes)?;
            total += bytes.len();
        }
        println!(
            "{:<14} {:>2} files, {:>7} bytes  {}",
            target.name(),
            list.len(),
            total,
            dir.display()
        );
    }
    let dict = root.join("../likeness.dict");
    std::fs::write(&dict, likeness_fuzzing::mutate::dictionary())?;
    println!("dictionary {}", dict.display());
    Ok(())
}
