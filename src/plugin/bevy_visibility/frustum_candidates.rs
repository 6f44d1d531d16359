//! The tree's candidates for a Bevy frustum, each with whether the tree
//! proves Bevy's own test would pass: the planes Bevy tests, moved out (to
//! miss nothing) and in (to prove) by more than either side's rounding.

use bevy_camera::primitives::Frustum as BevyFrustum;
use bevy_ecs::prelude::*;
use glam::Vec3;

use super::Renderable;
use crate::geometry::{Frustum, HalfSpace};
use crate::plugin::index::SpatialIndex;
use crate::query::QueryWorkspace;

/// The plane of a Bevy frustum that its camera culling does not test: the
/// far plane.
pub(super) const UNTESTED_BY_CAMERAS: usize = 5;

/// The plane of a shadow cascade that Bevy's directional light visibility
/// does not test: the near plane (a caster before it still casts).
#[cfg_attr(not(feature = "bevy_light"), allow(dead_code))]
pub(super) const UNTESTED_BY_CASCADES: usize = 4;

/// The tree's candidates for a Bevy frustum: every entry whose box passes
/// its planes (all but `untested`, the one plane Bevy's test skips: far for
/// cameras, near for shadow cascades), loosened by [`slack`] so that no box
/// Bevy's own test accepts is missed; and whether each box lies inside the
/// planes tightened by the same slack, which proves Bevy's tests would pass.
/// Returns how many were proven.
pub(super) fn candidates(
    index: &SpatialIndex<Renderable>,
    frustum: &BevyFrustum,
    untested: usize,
    eye: Vec3,
    ws: &mut QueryWorkspace,
    out: &mut Vec<(Entity, bool)>,
) -> usize {
    let tree = index.tree();
    let Some((loose, tight)) = proving_frustums(index, frustum, untested, eye) else {
        // A frustum Bevy's tests cannot decide either (NaN planes): every
        // entry is a candidate, and Bevy's tests say what they say.
        out.extend(tree.iter().map(|(_, entity, _)| (entity, false)));
        return 0;
    };
    let mut proven_count = 0;
    tree.visit_visible_proving(&loose, &tight, ws, |entity, proven| {
        proven_count += usize::from(proven);
        out.push((entity, proven))
    });
    proven_count
}

/// The planes the tree culls with for a Bevy frustum: loosened by
/// [`slack`], and tightened by it for the proof; `None` where Bevy's planes
/// are not usable (NaN).
fn proving_frustums(
    index: &SpatialIndex<Renderable>,
    frustum: &BevyFrustum,
    untested: usize,
    eye: Vec3,
) -> Option<(Frustum, Frustum)> {
    let bounds = index.tree().bounds()?;
    let reach =
        bounds.min.abs().max(bounds.max.abs()).max_element() * 3.0 + eye.abs().max_element();
    Some((
        rebased(frustum, untested, eye, reach, 1.0)?,
        rebased(frustum, untested, eye, reach, -1.0)?,
    ))
}

/// Bevy's planes but `untested`, re-based on `eye` and moved outward
/// (`side = 1`) or inward (`-1`) by [`slack`].
fn rebased(
    frustum: &BevyFrustum,
    untested: usize,
    eye: Vec3,
    reach: f32,
    side: f64,
) -> Option<Frustum> {
    let mut planes = [HalfSpace::INACTIVE; 6];
    for (i, (plane, half_space)) in planes.iter_mut().zip(&frustum.half_spaces).enumerate() {
        if i == untested {
            continue;
        }
        let normal = Vec3::from(half_space.normal());
        let d = half_space.d();
        let offset = d as f64 + normal.as_dvec3().dot(eye.as_dvec3());
        let moved = offset + side * slack(normal, d, reach);
        *plane = HalfSpace {
            normal,
            offset: moved as f32,
        };
    }
    Frustum::new(eye, planes).ok()
}

/// How far a plane is moved so that rounding cannot make the tree's test
/// and Bevy's disagree: Bevy evaluates `n·c + d + r` in `f32` at world
/// coordinates, with an error of a few `2^-24` of `|n|·|c| + |d| + r`; the
/// tree's box test errs likewise at eye-relative coordinates. `reach`
/// bounds `|c|`, `r` and the eye's distance from the origin (three times
/// the largest coordinate of the index, plus the eye's), and `2^-16` of
/// the magnitudes is over ten times both errors by a worst-case bound of
/// each: a few centimetres on a 2 km map, candidates the exact test then
/// decides. (A unit test holds the candidates and proofs to Bevy's own
/// tests at magnitudes from 1e-30 to 1e14 m, eyes near and far.)
pub(super) fn slack(normal: Vec3, d: f32, reach: f32) -> f64 {
    let magnitude = normal.length() as f64 * reach as f64 + (d as f64).abs();
    magnitude / 65_536.0
}
