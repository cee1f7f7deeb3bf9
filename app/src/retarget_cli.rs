//! `likeness retarget`: tracks + puppet (+ mapping) -> GLB animation, Live Link Face CSV or
//! JSON, with the mapping report printed.

use std::path::Path;

use anyhow::{Context, Result, bail};
use files::write_atomically;
use retarget::export::{
    clip_json, live_link_csv, parse_live_link_csv, retarget_clip, write_animation_glb,
};
use retarget::{MappingData, Puppet, Retargeter, Tracks};

/// Output formats, by file extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputFormat {
    Glb,
    Csv,
    Json,
}

impl OutputFormat {
    pub fn from_path(path: &Path) -> Result<Self> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("glb") => Ok(OutputFormat::Glb),
            Some("csv") => Ok(OutputFormat::Csv),
            Some("json") => Ok(OutputFormat::Json),
            _ => bail!(
                "--out {}: use a .glb, .csv or .json file name",
                path.display()
            ),
        }
    }
}

/// Reads tracks from tracking JSON or a Live Link Face CSV (by extension).
pub fn load_tracks(path: &Path) -> Result<Tracks> {
    let is_csv = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"));
    if is_csv {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        return parse_live_link_csv(&text)
            .map_err(|e| anyhow::anyhow!("{}: Live Link Face CSV: {e}", path.display()));
    }
    Ok(Tracks::load(path)?)
}

pub fn run(
    tracks_path: &Path,
    puppet_path: &Path,
    mapping_path: Option<&Path>,
    out: &Path,
) -> Result<()> {
    let format = OutputFormat::from_path(out)?;
    let tracks = load_tracks(tracks_path)?;
    if tracks.frames.is_empty() {
        bail!(
            "{}: no frame with a face to retarget",
            tracks_path.display()
        );
    }
    if !tracks.unknown_names.is_empty() {
        eprintln!(
            "warning: ignored {} unknown channel name(s) in the tracks: {}",
            tracks.unknown_names.len(),
            tracks.unknown_names.join(", ")
        );
    }
    let puppet = Puppet::load(puppet_path)?;
    let mapping = match mapping_path {
        Some(p) => MappingData::load(p)?,
        None => MappingData::load_for_puppet(puppet_path)?,
    };
    let retargeter = Retargeter::new(&puppet, &mapping);
    println!("{}", retargeter.report);
    if !retargeter.report.drives_anything() && retargeter.head_node().is_none() {
        bail!(
            "{}: none of its {} morph targets matches an ARKit channel or a VRM expression, and it has no head node; \
             write a mapping file ({}) that names the targets for each channel",
            puppet_path.display(),
            puppet.morph_target_count(),
            retarget::mapping::sidecar_path(puppet_path).display()
        );
    }
    let clip = retarget_clip(&retargeter, &tracks);
    match format {
        OutputFormat::Glb => write_animation_glb(&puppet, &retargeter, &clip, out)?,
        OutputFormat::Csv => write_atomically(out, live_link_csv(&retargeter, &tracks).as_bytes())?,
        OutputFormat::Json => {
            let text = serde_json::to_string_pretty(&clip_json(&puppet, &retargeter, &clip))?;
            write_atomically(out, text.as_bytes())?;
        }
    }
    println!(
        "wrote {} ({} frames, {:.2} s)",
        out.display(),
        clip.len(),
        clip.last().map_or(0.0, |f| f.time_s) - clip[0].time_s
    );
    Ok(())
}
