//! Frustum culling against the oracle: random scenes and views, and the
//! frustum hard cases of the contract (`docs/contract.md`).

mod common;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::{Aabb, CullMode, Frustum, HalfSpace, QueryWorkspace, RTree, SpatialError};
use glam::{EulerRot, Quat, Vec3};
use proptest::prelude::*;

#[path = "frustum/construction.rs"]
mod construction;
#[path = "frustum/degenerate.rs"]
mod degenerate;
#[path = "frustum/planes.rs"]
mod planes;

fn perspective() -> impl Strategy<Value = Frustum> {
    (
        common::grid_point(),
        0.0f32..std::f32::consts::TAU,
        -1.4f32..1.4,
        20f32..120.0,
        0.5f32..2.0,
        0.05f32..2.0,
        prop_oneof![3 => (1.0f32..30.0).prop_map(Some), 1 => Just(None)],
    )
        .prop_map(|(eye, yaw, pitch, fov, aspect, near, far)| {
            let rotation = Quat::from_euler(EulerRot::YXZ, yaw, pitch, 0.0);
            let far = far.map_or(f32::INFINITY, |f| near + f);
            Frustum::perspective(eye, rotation, fov.to_radians(), aspect, near, far).unwrap()
        })
}

/// Arbitrary half-space sets on the grid: possibly empty, unbounded or flat.
fn half_spaces() -> impl Strategy<Value = Frustum> {
    let plane = prop_oneof![
        4 => (-2i32..=2, -2i32..=2, -2i32..=2, -16i32..=16).prop_map(|(x, y, z, d)| {
            let normal = Vec3::new(x as f32, y as f32, z as f32);
            if normal == Vec3::ZERO { HalfSpace::INACTIVE } else { HalfSpace { normal, offset: d as f32 * 0.5 } }
        }),
        1 => Just(HalfSpace::INACTIVE),
    ];
    (common::grid_point(), prop::array::uniform6(plane))
        .prop_map(|(eye, planes)| Frustum::new(eye, planes).unwrap())
}

fn build(boxes: &[Aabb]) -> (RTree<u32, 4>, BruteForce<u32>) {
    let mut tree = RTree::<u32, 4>::with_settings(Default::default()).unwrap();
    let mut oracle = BruteForce::default();
    for (i, b) in boxes.iter().enumerate() {
        tree.insert(i as u32, *b).unwrap();
        oracle.insert(i as u32, *b);
    }
    (tree, oracle)
}

fn check_views(tree: &RTree<u32, 4>, oracle: &BruteForce<u32>, views: &[Frustum]) {
    let boxes: std::collections::HashMap<u32, Aabb> = oracle.entries().iter().copied().collect();
    for mode in [CullMode::Conservative, CullMode::Exact] {
        let mut out = vec![Vec::new(); views.len()];
        tree.visible_into(views, mode, &mut QueryWorkspace::default(), &mut out);
        // The visitor gets the same keys in the same order, each with its
        // own box (keys alone take another path through subtrees reported
        // whole, which skips the boxes).
        let mut visited = vec![Vec::new(); views.len()];
        tree.visit_visible(
            views,
            mode,
            &mut QueryWorkspace::default(),
            |view, key, aabb| {
                assert_eq!(Some(aabb), boxes.get(&key), "the box of {key}");
                visited[view].push(key);
                std::ops::ControlFlow::Continue(())
            },
        );
        assert_eq!(visited, out);
        for (view, keys) in views.iter().zip(out.iter_mut()) {
            keys.sort_unstable();
            assert_eq!(*keys, oracle.visible(view, mode), "{mode:?} {view:?}");
        }
    }
    // Exact mode only ever removes entries from the conservative answer,
    // and never one that has a point strictly inside every plane.
    for view in views {
        let exact = oracle.visible(view, CullMode::Exact);
        let conservative = oracle.visible(view, CullMode::Conservative);
        assert!(exact.iter().all(|k| conservative.binary_search(k).is_ok()));
        for (key, aabb) in oracle.entries() {
            if let Some(p) = sample_inside(view, aabb) {
                assert!(
                    exact.binary_search(key).is_ok(),
                    "exact mode culled {aabb:?}, which holds {p:?} inside {view:?}"
                );
            }
        }
    }
}

/// A point of `aabb` (on a 5 x 5 x 5 lattice over it) strictly inside every
/// active plane of `view`, computed in `f64`: a witness that the box is
/// visible, found without the crate's predicates.
fn sample_inside(view: &Frustum, aabb: &Aabb) -> Option<glam::DVec3> {
    let (min, max) = (aabb.min.as_dvec3(), aabb.max.as_dvec3());
    let eye = view.eye().as_dvec3();
    let steps = 4;
    (0..=steps)
        .flat_map(|i| (0..=steps).flat_map(move |j| (0..=steps).map(move |k| (i, j, k))))
        .map(|(i, j, k)| {
            let f = glam::DVec3::new(i as f64, j as f64, k as f64) / steps as f64;
            min + (max - min) * f
        })
        .find(|p| {
            view.planes()
                .iter()
                .filter(|h| !h.is_inactive())
                .all(|h| h.normal.as_dvec3().dot(*p - eye) + h.offset as f64 > 1e-9)
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn perspective_views_match_the_oracle(
        boxes in prop::collection::vec(common::grid_box(), 0..300),
        views in prop::collection::vec(perspective(), 1..11),
    ) {
        let (tree, oracle) = build(&boxes);
        check_views(&tree, &oracle, &views);
    }

    #[test]
    fn arbitrary_half_spaces_match_the_oracle(
        boxes in prop::collection::vec(common::grid_box(), 0..300),
        views in prop::collection::vec(half_spaces(), 1..4),
    ) {
        let (tree, oracle) = build(&boxes);
        check_views(&tree, &oracle, &views);
    }
}

/// The unit-box world plus 1,000 distractors, so pruning is exercised.
fn with_distractors(special: &[Aabb]) -> (Worlds, BruteForce<u32>) {
    let mut rng = bevy_rtree::scene::SceneRng::new(9);
    let mut boxes = special.to_vec();
    for _ in 0..1_000 {
        let c = Vec3::new(
            rng.range(-50.0, 50.0),
            rng.range(-50.0, 50.0),
            rng.range(-50.0, 50.0),
        );
        boxes.push(Aabb::new(c, c + Vec3::splat(rng.range(0.0, 2.0))).unwrap());
    }
    let (among, oracle) = build(&boxes);
    let (alone, alone_oracle) = build(special);
    let worlds = Worlds {
        among,
        alone,
        alone_oracle,
    };
    (worlds, oracle)
}

/// The hard cases among 1,000 distractors, and alone in a tree of their
/// own (SEMANTICS asks for both): `visible` answers for the first, after
/// holding the second to its own oracle on the same view.
struct Worlds {
    among: RTree<u32, 4>,
    alone: RTree<u32, 4>,
    alone_oracle: BruteForce<u32>,
}

impl Worlds {
    fn visible(&self, view: &Frustum, mode: CullMode) -> Vec<u32> {
        let alone = self.alone.visible(view, mode);
        assert_eq!(
            alone,
            self.alone_oracle.visible(view, mode),
            "the hard cases alone, {mode:?}"
        );
        self.among.visible(view, mode)
    }
}

impl std::ops::Deref for Worlds {
    type Target = RTree<u32, 4>;

    fn deref(&self) -> &RTree<u32, 4> {
        &self.among
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]

    /// A rotation that drifted from unit length orients the camera as its
    /// unit quaternion does: every plane of the frustum stays where the unit
    /// rotation puts it (up to the rounding of the normalization), so the
    /// near and far planes keep their distances from the eye.
    #[test]
    fn perspective_frustums_normalize_their_rotation(
        yaw in 0.0f32..std::f32::consts::TAU,
        pitch in -1.5f32..1.5,
        roll in -1.0f32..1.0,
        length in prop_oneof![
            0.5f32..2.0,
            1e-3f32..1e-2,
            1e2f32..1e3,
            // Where the squared length leaves `f32`'s normal range.
            1e-30f32..1e-20,
            1e20f32..1e30,
        ],
    ) {
        let unit = Quat::from_euler(EulerRot::YXZ, yaw, pitch, roll);
        let scaled = Quat::from_vec4(glam::Vec4::from(unit) * length);
        let eye = Vec3::new(3.0, -2.0, 7.0);
        let want = Frustum::perspective(eye, unit, 1.2, 1.6, 0.25, 80.0).unwrap();
        let got = Frustum::perspective(eye, scaled, 1.2, 1.6, 0.25, 80.0).unwrap();
        for (w, g) in want.planes().iter().zip(got.planes()) {
            prop_assert!(
                (w.normal - g.normal).length() <= 1e-5,
                "normal {} against {}", g.normal, w.normal
            );
            prop_assert!(
                (w.offset - g.offset).abs() <= 1e-5 * w.offset.abs().max(1.0),
                "offset {} against {}", g.offset, w.offset
            );
        }
    }
}
