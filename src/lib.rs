//! # bevy_rtree
//!
//! A wide, dynamic R-tree that keeps a spatial index of a game's entities
//! current as they move, and answers the queries a frame needs: frustum
//! culling for several views in one traversal, batched raycasts (first, all or
//! any hit), self and cross distance joins, box, sphere and point overlap, and
//! nearest neighbours. Use it through the ECS [`plugin`] or as a plain
//! [`RTree`].
//!
//! ```
//! use bevy_rtree::{Aabb, RTree};
//! use bevy_rtree::glam::Vec3;
//!
//! let mut tree = RTree::new();
//! let barrel = tree.insert(1u32, Aabb::new(Vec3::ZERO, Vec3::ONE)?)?;
//! tree.insert(2u32, Aabb::new(Vec3::splat(10.0), Vec3::splat(11.0))?)?;
//!
//! // Every frame: move what moved, then ask.
//! tree.update(barrel, Aabb::new(Vec3::splat(0.1), Vec3::splat(1.1))?)?;
//! assert_eq!(tree.containing_point(Vec3::splat(1.05)), vec![1]);
//! # Ok::<(), bevy_rtree::SpatialError>(())
//! ```
//!
//! ## In a Bevy app
//!
//! Add [`plugin::SpatialIndexPlugin`], give entities a
//! [`plugin::SpatialBounds`], and read each frame's answers from components
//! and resources (this is the `minimal` example):
//!
//! ```
//! use bevy_app::prelude::*;
//! use bevy_rtree::plugin::*;
//! use bevy_rtree::{Aabb, Ray, RayMode};
//! use bevy_rtree::glam::{Quat, Vec3};
//!
//! let mut app = App::new();
//! app.add_plugins(SpatialIndexPlugin::default());
//! let world = app.world_mut();
//! let at = |z: f32| SpatialBounds(Aabb::from_center_half_extents(Vec3::new(0.0, 0.0, z), Vec3::splat(0.5)).unwrap());
//! let near = world.spawn(at(-5.0)).id();
//! let far = world.spawn(at(-10.0)).id();
//! let behind = world.spawn(at(5.0)).id();
//! // A camera at the origin looking down -Z, and a ray the same way.
//! let camera = world.spawn(CullingCamera::perspective(Vec3::ZERO, Quat::IDENTITY, 1.0, 16.0 / 9.0, 0.1, 100.0)?).id();
//! let eye = world.spawn(RayCaster::new(Ray::new(Vec3::ZERO, Vec3::NEG_Z, 100.0)?, RayMode::First)).id();
//!
//! app.update();
//! let visible = app.world().get::<VisibleEntityList>(camera).unwrap();
//! assert!(visible.contains(near) && visible.contains(far) && !visible.contains(behind));
//! let hit = app.world().get::<RayCasterHits>(eye).unwrap().first().unwrap();
//! assert_eq!((hit.key, hit.t), (near, 4.5));
//! # Ok::<(), bevy_rtree::SpatialError>(())
//! ```
//!
//! The [`plugin`] module describes layers, joins, `SpatialQuery`, the
//! diagnostics and what happens to entities with bad boxes.
//!
//! ## In a Bevy game
//!
//! With feature `bevy_camera`, `BevyVisibilityPlugin` (added after
//! `SpatialIndexPlugin`) serves Bevy's own camera culling from the tree:
//! every entity Bevy's CPU culling tests (Bevy's `Aabb` and
//! `GlobalTransform`) is indexed with no component of the crate's, and
//! every `ViewVisibility` and each camera's `VisibleEntities` come out as
//! Bevy's own system makes them; with `bevy_light`, the shadow lists of
//! point, spot and directional lights too. Feature `bevy` gives
//! `LocalBounds`, a local box whose world box follows the entity's
//! `GlobalTransform`, and `bevy_camera` gives `FollowBevyFrustum`, which
//! makes a `CullingCamera` follow a Bevy camera's frustum. The README
//! shows the setup and lists every feature.
//!
//! ## The contract
//!
//! Every answer equals what a brute-force loop over all live entries returns
//! when it applies the same predicate (the [`oracle`] module is that loop),
//! whatever the tree's shape or the order of operations. The tree only prunes.
//!
//! - **Boxes** are closed, axis-aligned, stored as `min`/`max` in `f32`. Valid
//!   iff finite, `min <= max` per axis and every `|coordinate| <=`
//!   [`MAX_COORD`]. Points and flat boxes are valid. Faces, edges and corners
//!   belong to the box, so touching boxes overlap.
//! - **World boxes from transforms** ([`Aabb::transformed`]) are computed in
//!   `f64` and rounded outward to `f32`, so they contain the exact image of
//!   every corner of the local box, unless the transform is a pure
//!   translation (then `min + t`, `max + t` in `f32`).
//! - **Mutations are atomic**: `insert`, `update`, `remove` return `Result`;
//!   on `Err` the index is unchanged. An unknown or stale [`ProxyId`] is an
//!   error, never a panic. Enlarged ("fat") bounds are internal: acceptance
//!   of an entry always uses its exact current box.
//! - **Rays** ([`Ray`]) are closed segments `origin + t * dir`, `0 <= t <=
//!   max_t`; `t` is in units of `|dir|` (not normalised for you). Direction
//!   components below `f32::MIN_POSITIVE` in magnitude become `+0.0`; a zero
//!   direction, a non-finite origin or a negative / NaN `max_t` is an error.
//!   A ray hits a box by the slab test written with explicit comparisons
//!   (never `min`/`max`, whose NaN handling differs between targets); the
//!   entry `t` is `0` when the origin is inside or on the box. Grazing a face,
//!   an edge or a corner is a hit. A hit's `t` is a finite `f32`: an
//!   unbounded ray that would enter a box only beyond `f32::MAX` misses it.
//! - **First hit** is the hit with the smallest `(t, key)`; **all hits** are
//!   sorted by `(t, key)` and an optional limit cuts that list; **any hit**
//!   says whether one exists. In a batch, slot `i` answers ray `i` alone; an
//!   invalid ray gets an error in its own slot. Answers never depend on batch
//!   order, ray order or tree shape.
//! - **Frustums** ([`Frustum`]) are up to six half-spaces relative to an eye;
//!   `normal = 0, offset = +inf` is an inactive plane that never culls. In
//!   conservative mode a box is visible iff for every plane
//!   `dot(n, p - eye) + offset > 0` with `p` its corner furthest along `n`:
//!   a box touching a plane from outside is culled. Exact mode also requires
//!   that no separating axis exists (computed in `f64`), and sees nothing in
//!   a frustum whose open volume is empty.
//! - **Joins**: the distance between two closed boxes is the Euclidean norm
//!   of the per-axis gaps, in `f64`. A pair qualifies iff that distance is
//!   `<= d` (so `d = 0` pairs touching boxes), or, in Chebyshev mode, iff
//!   every gap is `<= d`. `d` must be finite and `>= 0`. A self join reports
//!   each unordered pair of distinct entries once as `(lo, hi)` by key; a
//!   cross join reports `(a, b)` with `a` from the first tree, `b` from the
//!   second, `a != b`. Lists are unordered unless a method says sorted.
//! - **Time**: a query sees the entries as of the last completed mutation; a
//!   removed entry never appears again. Answers are a pure function of the
//!   live `(key, box)` set and the query.
//! - **Validation**: [`RTree::validate`] checks links, reachability, bound
//!   containment, fan-out, equal leaf depth, entry counts, stored boxes and
//!   the node pool's free list.
//!
//! ## The queries
//!
//! | family | core (visitor) | conveniences |
//! |---|---|---|
//! | box / point overlap | [`RTree::visit_overlapping`] | `overlapping`, `overlapping_into`, `any_overlapping`, `containing_point` |
//! | frustum culling | [`RTree::visit_visible`] (up to 8 views per traversal) | `visible`, `visible_into` |
//! | raycasts | [`RTree::visit_ray`], [`RTree::cast_rays`] (batched) | `cast_ray`, `cast_ray_all`, `ray_hits_any` |
//! | distance joins | [`RTree::visit_self_join`], [`RTree::visit_cross_join`], [`RTree::visit_self_join_moved`] | `self_join`, `cross_join`, `*_into` |
//! | sphere overlap / within radius (distance to the closed box `<= r`) | [`RTree::visit_sphere`] | `overlapping_sphere`, `overlapping_sphere_into`, `any_overlapping_sphere`, `within_radius`, `within_radius_into` |
//! | k nearest neighbours (by `(distance_sq, key)`, optional inclusive max distance) | [`RTree::visit_nearest`] (depth first, nearest child first) | `nearest`, `nearest_into` |
//!
//! Every query takes a [`QueryWorkspace`] (or makes one): keep one per
//! system and a frame's queries do not allocate. Its [`QueryStats`] count
//! nodes visited and entries tested.
//!
//! With feature `parallel`, `par_cast_rays`, `par_visible_into`,
//! `par_self_join_into` and `par_cross_join_into` (with a
//! `ParallelWorkspace`) split a batch of rays, a cull or a join over
//! bevy_tasks' `ComputeTaskPool`, the pool a Bevy app already runs on, and
//! return exactly the single-threaded answers in the same order; the plugin's
//! query systems then use them.
//!
//! ## Accuracy options
//!
//! Two knobs trade precision for time. Neither drops a correct answer,
//! except that exact mode may miss slivers thinner than about 1e-11 of
//! their distance from the eye (a frustum of next to no volume, the edge
//! beside an endless wedge; contract, S7):
//! - [`CullMode::Conservative`] (default) may report a large box near a
//!   frustum edge that is really outside; [`CullMode::Exact`] removes those
//!   with a separating-axis test in `f64`.
//! - [`JoinMode::Chebyshev`] reports pairs whose gap is within `d` on every
//!   axis, a superset of the exact [`JoinMode::Euclidean`] pairs (default);
//!   measured on the standard scene it is no faster, and adds about 9 % pairs.
//!
//! The enlarged-bounds settings ([`TreeSettings`]) trade update time against
//! query work only: answers stay exact.
//!
//! The node split ([`TreeSettings::split`]) trades insert time against the
//! tree's shape. Measured on the standard scene at width 16, in one run on
//! a faster machine than the README's table (compare within a row;
//! `cargo bench --bench tree -- split/`, `docs/performance.md`):
//! 100,000 single inserts take 52 / 52 / 39 ms with
//! [`SplitStrategy::RStar`] / `Quadratic` / `Median`, a frame's 10,000
//! moves 0.41 / 0.43 / 0.43 ms, and 1,000 box queries on the churned tree
//! 0.139 / 0.164 / 0.146 ms (a bulk-loaded tree of the same boxes: 0.115
//! ms).
//! The R* split is the default: queries run every frame, and it leaves the
//! best tree.
//!
//! ## Node width
//!
//! `RTree<K, W>` takes 4, 8, 12 or 16 children per node (any multiple of
//! 4 up to 16); 16 is the default. Box, ray and frustum lane tests run four
//! lanes at a time, so a wider node costs little more to test and saves
//! levels: on the standard scene the tree is 5 levels deep instead of 6.
//! Measured in one run (a faster machine than the README's table) with
//! `cargo bench --bench tree` and `--bench queries`, width 8 against
//! width 16: bulk load 25.6 against 19.0 ms,
//! 1,000 box queries 0.24 against 0.19 ms, a cull 0.100 against 0.073 ms,
//! 1,000 incoherent rays 0.87 against 0.74 ms and the self join 8.2
//! against 6.6 ms; a frame's 10,000 moves cost the same within noise.
//! Sphere and nearest-neighbour queries were not compared.
//! `cargo run --release --example accuracy_cost --features bevy_camera`
//! compares widths 4, 8 and 16.
//!
//! ## Layout
//!
//! - [`prelude`]: what a game imports (`use bevy_rtree::prelude::*`);
//! - [`contract`]: the rules every answer is checked against;
//! - [`plugin`]: the bevy_ecs / bevy_app integration;
//! - [`geometry`]: boxes, rays, frustums, the error type and the predicates;
//! - [`tree`]: the R-tree and its maintenance;
//! - [`query`]: traversals and the [`oracle`];
//! - [`scene`]: the deterministic standard scene used by the examples and
//!   benchmarks.
//!
//! The crate's `unsafe` code is of three kinds, each documented with the
//! measurement that justifies it (`docs/performance.md`) and each block
//! with why it is sound (`// SAFETY:`):
//! - the cache prefetch hint in `tree/prefetch.rs`, which the updates and
//!   the queries use where it measured faster (box queries 10–20 %, the
//!   cold cull a third and more);
//! - calls into twins compiled for AVX or AVX-512, made only once a
//!   run-time check has found those instructions: from the single-ray walk
//!   (`query/ray.rs`), a batch's pairs of rays from one point
//!   (`query/ray_batch.rs`) and the self and cross joins (`query/join.rs`,
//!   `query/cross_join.rs`) into `query/ray_avx.rs`, `query/ray_avx512.rs`
//!   and `query/join_avx512.rs` (rays 11–15 % faster, the self join
//!   12–17 %), and from the AVX-512 ray walk into its placing of children,
//!   an `unsafe fn` so that it can be inlined there (3 % faster);
//! - AVX-512 intrinsics in `query/ray_avx512.rs` (that placing) and
//!   `query/join_avx512.rs` (a sixteen-lane load of a bounds-checked
//!   slice).
//!
//! Tests hold every twin to its scalar path on processors that have its
//! instructions. Everything else is safe code.
// On docs.rs, each item behind a feature says which.
#![cfg_attr(docsrs, feature(doc_cfg))]
// Without the plugin, the crate docs' links to it have nothing to name.
#![cfg_attr(not(feature = "plugin"), allow(rustdoc::broken_intra_doc_links))]
// `deny` rather than `forbid` so that the fenced places can allow it.
#![deny(unsafe_code)]
#![warn(missing_docs)]

pub mod contract;
pub mod geometry;
#[cfg(feature = "plugin")]
pub mod plugin;
pub mod prelude;
pub mod query;
pub mod scene;
pub mod tree;

/// The `glam` the crate's types are made of: 0.33, the version Bevy 0.20's
/// `bevy_math` uses, so `Vec3` and `Quat` from either are the same types.
/// Use it (or `bevy_rtree::prelude`) instead of adding `glam` yourself: a
/// `glam = "0.34"` line would bring a second, incompatible `Vec3`.
pub use glam;

pub use geometry::{
    Aabb, Frustum, FrustumSat, HalfSpace, MAX_COORD, PreparedRay, Ray, SpatialError,
};
#[cfg(feature = "parallel")]
pub use query::ParallelWorkspace;
pub use query::{
    CullMode, JoinMode, Neighbor, QueryWorkspace, RayHit, RayMode, RayResults, oracle,
};
pub use tree::{
    InvariantViolation, MaintenanceStats, MemoryUse, MoveKind, ProxyId, QueryStats, RTree,
    RebuildWork, SplitStrategy, TreeSettings,
};

// The README's code blocks compile and run as doc tests (with the feature
// its first block needs; CI runs the doc tests with it).
#[cfg(all(doctest, feature = "bevy_camera"))]
#[doc = include_str!("../README.md")]
struct ReadmeDoctests;
