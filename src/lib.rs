//! # bevy_rtree
//!
//! A wide, dynamic R-tree that keeps a spatial index of a game's entities
//! current as they move, and answers the queries a frame needs: box and point
//! overlap now, with frustum culling, batched raycasts and spatial joins built
//! on the same tree.
//!
//! ```
//! use bevy_rtree::{Aabb, RTree};
//! use glam::Vec3;
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
//! - **World boxes from transforms** ([`Aabb::transformed`]) are rounded
//!   outward by one ulp unless the transform is a pure translation.
//! - **Mutations are atomic**: `insert`, `update`, `remove` return `Result`;
//!   on `Err` the index is unchanged. An unknown or stale [`ProxyId`] is an
//!   error, never a panic. Enlarged ("fat") bounds are internal: acceptance
//!   of an entry always uses its exact current box.
//! - **Rays** ([`Ray`]) are closed segments `origin + t * dir`, `0 <= t <=
//!   max_t`; `t` is in units of `|dir|`. Direction components below
//!   `f32::MIN_POSITIVE` in magnitude become `+0.0`; a zero direction, a
//!   non-finite origin or a negative / NaN `max_t` is an error.
//! - **Frustums** ([`Frustum`]) are up to six eye-relative half-spaces; a box
//!   is visible in conservative mode iff its furthest corner along every
//!   plane normal is strictly inside.
//! - **Distances** between boxes are Euclidean gaps computed in `f64`; a
//!   join distance must be finite and `>= 0`.
//! - **Time**: a query sees the entries as of the last completed mutation; a
//!   removed entry never appears again. Answers are a pure function of the
//!   live `(key, box)` set and the query.
//!
//! ## Layout
//!
//! - [`geometry`]: boxes, rays, frustums, the error type and the predicates;
//! - [`tree`]: the R-tree and its maintenance;
//! - [`query`]: traversals and the [`oracle`];
//! - [`scene`]: the deterministic standard scene used by the examples and
//!   benchmarks.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod geometry;
pub mod query;
pub mod scene;
pub mod tree;

pub use geometry::{Aabb, Frustum, FrustumSat, HalfSpace, MAX_COORD, Ray, SpatialError};
pub use query::{CullMode, JoinMode, QueryWorkspace, RayHit, RayMode, RayResults, oracle};
pub use tree::{
    InvariantViolation, MaintenanceStats, MoveKind, ProxyId, QueryStats, RTree, TreeSettings,
};
