//! Driving a puppet: the compiled mapping (automatic by names, or the sidecar's entries),
//! its report, and the puppet pose for one tracked frame.
//!
//! Automatic mapping: a morph target whose name is an ARKit channel in any convention is
//! driven by that channel; a VRM expression named as an ARKit channel ("perfect sync") by
//! that channel; a VRM preset by its formula (`vrm`). An expression none of whose morph
//! targets is already driven directly is used; otherwise it is skipped (it would drive
//! the same target twice) and the report says so.

use std::collections::BTreeMap;
use std::fmt;

use face::names::{ARKIT_NAMES, NUM_ARKIT};
use glam::Quat;

use crate::mapping::{ChannelMapping, HeadMapping, MappingData, Source, calibrate};
use crate::names::{arkit_channel, canonical};
use crate::puppet::Puppet;
use crate::vrm::{Override, OverrideGroup, VrmExpression, VrmPreset};

/// What a link drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Target {
    Morph {
        mesh: usize,
        target: usize,
    },
    /// Index into the puppet's VRM expressions.
    Expression(usize),
}

#[derive(Clone, Debug, PartialEq)]
pub struct Link {
    pub source: Source,
    pub response: ChannelMapping,
    pub targets: Vec<Target>,
}

/// What the mapping does, for people: printed by the CLI, shown by the studio.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MappingReport {
    /// Source channel -> the targets it drives.
    pub mapped: Vec<(String, Vec<String>)>,
    /// Morph targets and VRM expressions nothing drives.
    pub unmapped_targets: Vec<String>,
    /// ARKit channels that drive nothing.
    pub unused_sources: Vec<String>,
    /// One channel driving several targets of the same mesh (e.g. `jawOpen` and `JawOpen`).
    pub ambiguous: Vec<String>,
    /// Target names in the mapping data that match nothing in the puppet.
    pub unresolved: Vec<String>,
    /// VRM expressions not used because their morph targets are driven directly.
    pub skipped_expressions: Vec<String>,
    /// VRM expressions that move nothing (no morph target bind with a weight), so nothing
    /// is mapped to them.
    pub empty_expressions: Vec<String>,
    /// The node head rotation drives, if any.
    pub head_node: Option<String>,
}

impl MappingReport {
    /// True when the puppet moves at all.
    pub fn drives_anything(&self) -> bool {
        !self.mapped.is_empty()
    }
}

impl fmt::Display for MappingReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "mapped {} channel(s):", self.mapped.len())?;
        for (source, targets) in &self.mapped {
            writeln!(f, "  {source:<22} -> {}", targets.join(", "))?;
        }
        let list = |f: &mut fmt::Formatter<'_>, title: &str, items: &[String]| -> fmt::Result {
            if !items.is_empty() {
                writeln!(f, "{title} ({}): {}", items.len(), items.join(", "))?;
            }
            Ok(())
        };
        list(f, "unmapped puppet targets", &self.unmapped_targets)?;
        list(f, "tracked channels driving nothing", &self.unused_sources)?;
        list(f, "ambiguous", &self.ambiguous)?;
        list(f, "mapping names matching nothing", &self.unresolved)?;
        list(
            f,
            "VRM expressions skipped (their morph targets are driven directly)",
            &self.skipped_expressions,
        )?;
        list(
            f,
            "VRM expressions moving nothing (no morph target binds)",
            &self.empty_expressions,
        )?;
        match &self.head_node {
            Some(n) => writeln!(f, "head rotation drives node `{n}`"),
            None => writeln!(f, "head rotation: no head or neck node found"),
        }
    }
}

/// One frame's puppet state.
#[derive(Clone, Debug, PartialEq)]
pub struct PuppetPose {
    /// Per mesh, one weight per morph target.
    pub morph_weights: Vec<Vec<f32>>,
    /// Per VRM expression, its weight after binary and override rules.
    pub expression_weights: Vec<f32>,
    /// The head node's new local rotation.
    pub head: Option<(usize, Quat)>,
}

/// A puppet's compiled mapping.
#[derive(Clone, Debug)]
pub struct Retargeter {
    pub links: Vec<Link>,
    pub neutral: [f32; NUM_ARKIT],
    pub head: HeadMapping,
    head_node: Option<usize>,
    /// Rest local rotation of the head node and its parent's rest world rotation.
    head_rest: (Quat, Quat),
    expressions: Vec<VrmExpression>,
    default_weights: Vec<Vec<f32>>,
    driven: Vec<Vec<bool>>,
    pub report: MappingReport,
}

fn target_label(puppet: &Puppet, t: Target) -> String {
    match t {
        Target::Morph { mesh, target } => {
            let m = &puppet.meshes[mesh];
            format!("{}/{}", m.name, m.target_names[target])
        }
        Target::Expression(k) => format!(
            "vrm:{}",
            puppet
                .vrm
                .as_ref()
                .map_or("?", |v| v.expressions[k].name.as_str())
        ),
    }
}

impl Retargeter {
    pub fn new(puppet: &Puppet, mapping: &MappingData) -> Self {
        let expressions: Vec<VrmExpression> = puppet
            .vrm
            .as_ref()
            .map(|v| v.expressions.clone())
            .unwrap_or_default();
        let mut report = MappingReport::default();

        // Automatic targets per source.
        let mut auto: BTreeMap<Source, Vec<Target>> = BTreeMap::new();
        let mut direct = vec![Vec::<bool>::new(); puppet.meshes.len()];
        for (m, mesh) in puppet.meshes.iter().enumerate() {
            direct[m] = vec![false; mesh.target_names.len()];
            for (t, name) in mesh.target_names.iter().enumerate() {
                if let Some(a) = arkit_channel(name) {
                    auto.entry(Source::Arkit(a))
                        .or_default()
                        .push(Target::Morph { mesh: m, target: t });
                    direct[m][t] = true;
                }
            }
        }
        let moves_something = |e: &VrmExpression| e.binds.iter().any(|b| b.weight != 0.0);
        for e in &expressions {
            if !moves_something(e) && e.preset != Some(VrmPreset::Neutral) {
                report.empty_expressions.push(e.name.clone());
            }
        }
        for (k, e) in expressions.iter().enumerate() {
            if !moves_something(e) {
                continue;
            }
            let source = arkit_channel(&e.name).map(Source::Arkit).or_else(|| {
                e.preset
                    .filter(|p| *p != VrmPreset::Neutral)
                    .map(Source::Vrm)
            });
            let Some(source) = source else { continue };
            if e.binds.iter().any(|b| {
                direct
                    .get(b.mesh)
                    .and_then(|d| d.get(b.target))
                    .copied()
                    .unwrap_or(false)
            }) {
                report.skipped_expressions.push(e.name.clone());
                continue;
            }
            auto.entry(source).or_default().push(Target::Expression(k));
        }

        // Explicit entries replace their source's automatic link.
        let mut links = Vec::new();
        let explicit: Vec<(Source, &ChannelMapping)> = mapping
            .channels
            .iter()
            .filter_map(|c| Source::parse(&c.source).map(|s| (s, c)))
            .collect();
        for (source, targets) in &auto {
            if explicit.iter().all(|(s, _)| s != source) {
                links.push(Link {
                    source: *source,
                    response: ChannelMapping::identity(source.name()),
                    targets: targets.clone(),
                });
            }
        }
        for (source, entry) in &explicit {
            let targets = if entry.targets.is_empty() {
                auto.get(source).cloned().unwrap_or_default()
            } else {
                let mut found = Vec::new();
                for name in &entry.targets {
                    let mut resolved = resolve_target(puppet, &expressions, name);
                    resolved.retain(|t| match *t {
                        Target::Expression(k) => moves_something(&expressions[k]),
                        Target::Morph { .. } => true,
                    });
                    if resolved.is_empty() {
                        report
                            .unresolved
                            .push(format!("{name} (for {})", entry.source));
                    }
                    found.extend(resolved);
                }
                found
            };
            links.push(Link {
                source: *source,
                response: (*entry).clone(),
                targets,
            });
        }
        links.retain(|l| !l.targets.is_empty());
        links.sort_by_key(|l| l.source);

        // The report.
        let mut driven = vec![Vec::<bool>::new(); puppet.meshes.len()];
        for (m, mesh) in puppet.meshes.iter().enumerate() {
            driven[m] = vec![false; mesh.target_names.len()];
        }
        let mut expression_driven = vec![false; expressions.len()];
        let mut used = [false; NUM_ARKIT];
        for link in &links {
            match link.source {
                Source::Arkit(a) => used[a] = true,
                Source::Vrm(p) => {
                    for a in preset_inputs(p) {
                        used[a] = true;
                    }
                }
            }
            for &t in &link.targets {
                match t {
                    Target::Morph { mesh, target } => driven[mesh][target] = true,
                    Target::Expression(k) => {
                        expression_driven[k] = true;
                        for b in &expressions[k].binds {
                            driven[b.mesh][b.target] = true;
                        }
                    }
                }
            }
            let mut per_mesh: BTreeMap<usize, Vec<String>> = BTreeMap::new();
            for &t in &link.targets {
                if let Target::Morph { mesh, target } = t {
                    per_mesh
                        .entry(mesh)
                        .or_default()
                        .push(puppet.meshes[mesh].target_names[target].clone());
                }
            }
            for (mesh, names) in per_mesh.into_iter().filter(|(_, n)| n.len() > 1) {
                report.ambiguous.push(format!(
                    "{} drives {} targets of mesh `{}`: {}",
                    link.source.name(),
                    names.len(),
                    puppet.meshes[mesh].name,
                    names.join(", ")
                ));
            }
            report.mapped.push((
                link.source.name(),
                link.targets
                    .iter()
                    .map(|&t| target_label(puppet, t))
                    .collect(),
            ));
        }
        for (m, mesh) in puppet.meshes.iter().enumerate() {
            for (t, name) in mesh.target_names.iter().enumerate() {
                if !driven[m][t] {
                    report
                        .unmapped_targets
                        .push(format!("{}/{name}", mesh.name));
                }
            }
        }
        for (k, e) in expressions.iter().enumerate() {
            if !expression_driven[k]
                && !report.skipped_expressions.contains(&e.name)
                && !report.empty_expressions.contains(&e.name)
                && e.preset != Some(VrmPreset::Neutral)
            {
                report.unmapped_targets.push(format!("vrm:{}", e.name));
            }
        }
        report.unused_sources = (0..NUM_ARKIT)
            .filter(|&a| !used[a])
            .map(|a| ARKIT_NAMES[a].to_owned())
            .collect();

        let head_node = if mapping.head.enabled {
            puppet.head_node(mapping.head.node.as_deref())
        } else {
            None
        };
        report.head_node = head_node.map(|h| puppet.nodes[h].name.clone());
        let head_rest = head_node.map_or((Quat::IDENTITY, Quat::IDENTITY), |h| {
            let parent_world = puppet.nodes[h].parent.map_or(Quat::IDENTITY, |p| {
                let (_, r, _) = puppet.world_matrices(&[])[p].to_scale_rotation_translation();
                if r.is_finite() { r } else { Quat::IDENTITY }
            });
            (puppet.nodes[h].rotation, parent_world)
        });
        Retargeter {
            links,
            neutral: mapping.neutral_weights(),
            head: mapping.head.clone(),
            head_node,
            head_rest,
            expressions,
            default_weights: puppet
                .meshes
                .iter()
                .map(|m| m.default_weights.clone())
                .collect(),
            driven,
            report,
        }
    }

    pub fn head_node(&self) -> Option<usize> {
        self.head_node
    }

    /// Whether any morph target of mesh `m` is driven (directly or through an expression).
    pub fn drives_mesh(&self, m: usize) -> bool {
        self.driven.get(m).is_some_and(|d| d.iter().any(|&x| x))
    }

    /// Tracked weights after the neutral calibration (step 1 of every response), clamped to
    /// [0, 1], non-finite values read as 0.
    pub fn calibrated(&self, arkit: &[f32; NUM_ARKIT]) -> [f32; NUM_ARKIT] {
        let mut out = [0.0f32; NUM_ARKIT];
        for a in 0..NUM_ARKIT {
            let x = if arkit[a].is_finite() {
                arkit[a].clamp(0.0, 1.0)
            } else {
                0.0
            };
            out[a] = calibrate(x, self.neutral[a]);
        }
        out
    }

    /// The puppet's pose for ARKit weights and an optional head rotation `[yaw, pitch,
    /// roll]` in degrees (the tracker's convention, `face::camera`).
    pub fn pose(&self, arkit: &[f32; NUM_ARKIT], rotation_deg: Option<[f32; 3]>) -> PuppetPose {
        let calibrated = self.calibrated(arkit);
        let mut morph: Vec<Vec<f32>> = self.driven.iter().map(|d| vec![0.0; d.len()]).collect();
        let mut expression = vec![0.0f32; self.expressions.len()];
        for link in &self.links {
            let x = match link.source {
                Source::Arkit(a) => calibrated[a],
                Source::Vrm(p) => p.weight(&calibrated),
            };
            let y = link.response.respond(x);
            for &t in &link.targets {
                match t {
                    Target::Morph { mesh, target } => morph[mesh][target] += y,
                    Target::Expression(k) => expression[k] += y,
                }
            }
        }
        for (k, e) in self.expressions.iter().enumerate() {
            let w = expression[k].clamp(0.0, 1.0);
            expression[k] = if e.is_binary {
                if w > 0.5 { 1.0 } else { 0.0 }
            } else {
                w
            };
        }
        // VRM 1.0 overrides: an active expression blocks or fades a group.
        let mut group_scale = [1.0f32; 3];
        for (k, e) in self.expressions.iter().enumerate() {
            let w = expression[k];
            if w <= 0.0 {
                continue;
            }
            for (slot, o) in [
                (0, e.override_blink),
                (1, e.override_look_at),
                (2, e.override_mouth),
            ] {
                let s = match o {
                    Override::None => 1.0,
                    Override::Block => 0.0,
                    Override::Blend => 1.0 - w,
                };
                group_scale[slot] = group_scale[slot].min(s);
            }
        }
        for (k, e) in self.expressions.iter().enumerate() {
            let scale = match e.preset.and_then(VrmPreset::group) {
                Some(OverrideGroup::Blink) => group_scale[0],
                Some(OverrideGroup::LookAt) => group_scale[1],
                Some(OverrideGroup::Mouth) => group_scale[2],
                None => 1.0,
            };
            expression[k] *= scale;
            for b in &e.binds {
                morph[b.mesh][b.target] += expression[k] * b.weight;
            }
        }
        for (m, weights) in morph.iter_mut().enumerate() {
            for (t, w) in weights.iter_mut().enumerate() {
                *w = if self.driven[m][t] {
                    w.clamp(0.0, 1.0)
                } else {
                    self.default_weights[m][t]
                };
            }
        }
        let head = match (self.head_node, rotation_deg) {
            (Some(h), Some(r)) if self.head.enabled && r.iter().all(|v| v.is_finite()) => {
                Some((h, self.head_rotation(r)))
            }
            _ => None,
        };
        PuppetPose {
            morph_weights: morph,
            expression_weights: expression,
            head,
        }
    }

    /// The head node's local rotation for a tracked head rotation: the rotation is applied
    /// in world axes (so bones with any local axes turn the same way), i.e.
    /// `local' = P^-1 R P local` with `P` the parent's rest world rotation.
    pub fn head_rotation(&self, rotation_deg: [f32; 3]) -> Quat {
        let g = self.head.gain;
        let sign = if self.head.mirror { -1.0 } else { 1.0 };
        let [yaw, pitch, roll] = rotation_deg;
        let euler = glam::Vec3::new(
            (sign * yaw * g).to_radians(),
            (pitch * g).to_radians(),
            (sign * roll * g).to_radians(),
        );
        let r = Quat::from_mat3(&face::camera::euler_to_matrix(euler));
        let (rest_local, parent_world) = self.head_rest;
        let turned = (parent_world.inverse() * r * parent_world * rest_local).normalize();
        // Degenerate node transforms (a zero scale) have no rotation to turn in: the head
        // stays at rest rather than becoming NaN.
        if turned.is_finite() {
            turned
        } else {
            rest_local
        }
    }
}

/// Names resolve to morph targets by exact name, else by canonical ARKit-style name, else to
/// VRM expressions (by name or preset).
fn resolve_target(puppet: &Puppet, expressions: &[VrmExpression], name: &str) -> Vec<Target> {
    let exact: Vec<Target> = puppet
        .morph_targets()
        .filter(|(_, _, n)| *n == name)
        .map(|(mesh, target, _)| Target::Morph { mesh, target })
        .collect();
    if !exact.is_empty() {
        return exact;
    }
    let key = canonical(name);
    let loose: Vec<Target> = puppet
        .morph_targets()
        .filter(|(_, _, n)| canonical(n) == key)
        .map(|(mesh, target, _)| Target::Morph { mesh, target })
        .collect();
    if !loose.is_empty() {
        return loose;
    }
    let wanted = name.strip_prefix("vrm:").unwrap_or(name);
    let preset = VrmPreset::parse(wanted);
    expressions
        .iter()
        .enumerate()
        .filter(|(_, e)| {
            e.name.eq_ignore_ascii_case(wanted) || (preset.is_some() && e.preset == preset)
        })
        .map(|(k, _)| Target::Expression(k))
        .collect()
}

/// The ARKit channels a preset formula reads (for the "driving nothing" report).
fn preset_inputs(p: VrmPreset) -> Vec<usize> {
    p.inputs()
        .iter()
        .filter_map(|n| face::names::arkit_index(n))
        .collect()
}
