//! Registered spatial joins: every frame, the pairs of two layers (or of one
//! layer with itself) within a distance, and the pairs that started or ended.

use super::frame_queries::{self, FrameWorkspace};
use std::any::TypeId;
use std::marker::PhantomData;

use bevy_ecs::prelude::*;

use super::diagnostics::DiagnosticsSink;
use super::index::SpatialIndex;
use crate::SpatialError;
use crate::query::JoinMode;

/// The pairs of a join registered with
/// [`add_spatial_join::<A, B>`](super::SpatialAppExt::add_spatial_join):
/// every `(a, b)` with `a` in layer `A`, `b` in layer `B`, `a != b`, whose
/// boxes are within [`distance`](Self::distance) ([contract S8](crate::contract)), sorted.
///
/// For a self join (`A == B`) each unordered pair appears once, as
/// `(smaller, larger)` entity. Change `distance` or `mode` at any time; the
/// next frame uses them. The join runs only while both layers have entities
/// and something in them changed since its last run.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_ecs::prelude::*;
/// use bevy_rtree::{Aabb, JoinMode};
/// use bevy_rtree::plugin::{SpatialAppExt, SpatialBounds, SpatialIndexPlugin, SpatialJoin};
/// use bevy_rtree::glam::Vec3;
///
/// #[derive(Component)]
/// struct Enemy;
/// #[derive(Component)]
/// struct Barrel;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default())
///     .add_spatial_join::<Enemy, Barrel>(5.0, JoinMode::Euclidean);
/// let unit = |x: f32| SpatialBounds(Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0)).unwrap());
/// let enemy = app.world_mut().spawn((unit(0.0), Enemy)).id();
/// let near = app.world_mut().spawn((unit(4.0), Barrel)).id();
/// let _far = app.world_mut().spawn((unit(50.0), Barrel)).id();
/// app.update();
/// let join = app.world().resource::<SpatialJoin<Enemy, Barrel>>();
/// assert_eq!(join.pairs(), [(enemy, near)]);
/// ```
#[derive(Resource)]
pub struct SpatialJoin<A: Component, B: Component> {
    /// Pairs are boxes at most this far apart, in metres.
    pub distance: f32,
    /// Euclidean (exact box distance) or Chebyshev (per-axis gap).
    pub mode: JoinMode,
    pairs: Vec<(Entity, Entity)>,
    previous: Vec<(Entity, Entity)>,
    /// What the pairs were computed from: both layers' generations, the
    /// distance and the mode.
    computed_from: Option<(u64, u64, u32, JoinMode)>,
    workspace: FrameWorkspace,
    _layers: PhantomData<fn() -> (A, B)>,
}

impl<A: Component, B: Component> SpatialJoin<A, B> {
    pub(crate) fn new(distance: f32, mode: JoinMode) -> Self {
        SpatialJoin {
            distance,
            mode,
            pairs: Vec::new(),
            previous: Vec::new(),
            computed_from: None,
            workspace: FrameWorkspace::default(),
            _layers: PhantomData,
        }
    }

    /// This frame's pairs, sorted, as computed in the plugin's schedule
    /// (`PostUpdate` unless the plugin was given another): an entity
    /// despawned since is still named until the next run ([contract
    /// S9](crate::contract)), so look the entities up with `Query::get`.
    pub fn pairs(&self) -> &[(Entity, Entity)] {
        &self.pairs
    }

    /// Why the join has no pairs, if its `distance` is refused
    /// (`SpatialError::InvalidDistance`: negative, NaN or infinite). The
    /// join then reports no pair until the distance is fixed, and is not
    /// run again while only the layers change.
    ///
    /// ```
    /// use bevy_app::prelude::*;
    /// use bevy_rtree::prelude::*;
    ///
    /// # #[derive(bevy_ecs::component::Component)]
    /// # struct Enemy;
    /// # #[derive(bevy_ecs::component::Component)]
    /// # struct Barrel;
    /// let mut app = App::new();
    /// app.add_plugins(SpatialIndexPlugin::default())
    ///     .add_spatial_join::<Enemy, Barrel>(-5.0, JoinMode::Euclidean);
    /// app.world_mut().spawn((SpatialBounds(Aabb::new(Vec3::ZERO, Vec3::ONE)?), Enemy));
    /// app.world_mut().spawn((SpatialBounds(Aabb::new(Vec3::ZERO, Vec3::ONE)?), Barrel));
    /// app.update();
    /// let join = app.world().resource::<SpatialJoin<Enemy, Barrel>>();
    /// assert_eq!(join.error(), Some(SpatialError::InvalidDistance));
    /// assert!(join.pairs().is_empty());
    /// # Ok::<(), SpatialError>(())
    /// ```
    pub fn error(&self) -> Option<SpatialError> {
        // The distance as it is now, whether or not the join has run since.
        crate::geometry::predicates::check_distance(self.distance).err()
    }
}

/// Sent when a pair of join `A`×`B` appears (it was not a pair last frame).
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_ecs::prelude::*;
/// use bevy_rtree::prelude::*;
///
/// #[derive(Component)]
/// struct Enemy;
/// #[derive(Component)]
/// struct Barrel;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default())
///     .add_spatial_join::<Enemy, Barrel>(5.0, JoinMode::Euclidean);
/// let near = |x: f32| Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0));
/// let enemy = app.world_mut().spawn((SpatialBounds(near(0.0)?), Enemy)).id();
/// let barrel = app.world_mut().spawn((SpatialBounds(near(3.0)?), Barrel)).id();
/// app.update();
/// let started = app.world().resource::<Messages<PairStarted<Enemy, Barrel>>>();
/// let pairs: Vec<_> = started.iter_current_update_messages().map(|m| (m.a, m.b)).collect();
/// assert_eq!(pairs, [(enemy, barrel)]);
/// # Ok::<(), SpatialError>(())
/// ```
#[derive(Message)]
pub struct PairStarted<A: Component, B: Component> {
    /// The entity of layer `A`.
    pub a: Entity,
    /// The entity of layer `B`.
    pub b: Entity,
    _layers: PhantomData<fn() -> (A, B)>,
}

/// Sent when a pair of join `A`×`B` disappears (moved apart, despawned, left
/// a layer).
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_ecs::prelude::*;
/// use bevy_rtree::prelude::*;
///
/// #[derive(Component)]
/// struct Enemy;
/// #[derive(Component)]
/// struct Barrel;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default())
///     .add_spatial_join::<Enemy, Barrel>(5.0, JoinMode::Euclidean);
/// let unit = Aabb::new(Vec3::ZERO, Vec3::ONE)?;
/// app.world_mut().spawn((SpatialBounds(unit), Enemy));
/// let barrel = app.world_mut().spawn((SpatialBounds(unit), Barrel)).id();
/// app.update();
/// // The barrel is despawned: the pair ends the next frame.
/// app.world_mut().despawn(barrel);
/// app.update();
/// let ended = app.world().resource::<Messages<PairEnded<Enemy, Barrel>>>();
/// assert_eq!(ended.iter_current_update_messages().map(|m| m.b).collect::<Vec<_>>(), [barrel]);
/// # Ok::<(), SpatialError>(())
/// ```
#[derive(Message)]
pub struct PairEnded<A: Component, B: Component> {
    /// The entity of layer `A`.
    pub a: Entity,
    /// The entity of layer `B`.
    pub b: Entity,
    _layers: PhantomData<fn() -> (A, B)>,
}

impl_layer_generic_traits!(PairStarted<A, B> { a, b });
impl_layer_generic_traits!(PairEnded<A, B> { a, b });

impl<A: Component, B: Component> PartialEq for PairStarted<A, B> {
    fn eq(&self, other: &Self) -> bool {
        (self.a, self.b) == (other.a, other.b)
    }
}

impl<A: Component, B: Component> PartialEq for PairEnded<A, B> {
    fn eq(&self, other: &Self) -> bool {
        (self.a, self.b) == (other.a, other.b)
    }
}

impl<A: Component, B: Component> PairStarted<A, B> {
    fn new((a, b): (Entity, Entity)) -> Self {
        PairStarted {
            a,
            b,
            _layers: PhantomData,
        }
    }
}

impl<A: Component, B: Component> PairEnded<A, B> {
    fn new((a, b): (Entity, Entity)) -> Self {
        PairEnded {
            a,
            b,
            _layers: PhantomData,
        }
    }
}

/// Run condition: the join has something to compute (both layers populated)
/// or to clear (pairs left over from when they were).
pub(crate) fn join_has_work<A: Component, B: Component>(
    join: Res<SpatialJoin<A, B>>,
    a: Res<SpatialIndex<A>>,
    b: Res<SpatialIndex<B>>,
) -> bool {
    (!a.is_empty() && !b.is_empty()) || !join.pairs.is_empty()
}

/// Recomputes the join if either layer (or the join's settings) changed,
/// then reports the difference from last frame as messages.
pub(crate) fn run_join<A: Component, B: Component>(
    mut join: ResMut<SpatialJoin<A, B>>,
    a: Res<SpatialIndex<A>>,
    b: Res<SpatialIndex<B>>,
    mut started: MessageWriter<PairStarted<A, B>>,
    mut ended: MessageWriter<PairEnded<A, B>>,
    sink: Res<DiagnosticsSink>,
) {
    let join = &mut *join;
    // The distance by its bits, so that a NaN distance compares equal to
    // itself and is reported once, not every frame.
    let bits = join.distance.to_bits();
    let key = (a.generation(), b.generation(), bits, join.mode);
    // A refused distance that was already run (pairs cleared, warned)
    // waits for a valid one, whatever the layers do.
    let refused_again =
        join.computed_from.is_some_and(|(.., was, _)| was == bits) && join.error().is_some();
    if join.computed_from == Some(key) || refused_again {
        return;
    }
    join.computed_from = Some(key);
    std::mem::swap(&mut join.pairs, &mut join.previous);
    join.pairs.clear();
    let self_join = TypeId::of::<A>() == TypeId::of::<B>();
    // The tree's self join already reports each pair as (smaller, larger).
    let result = if self_join {
        frame_queries::self_join_into(
            a.tree(),
            join.distance,
            join.mode,
            &mut join.workspace,
            &mut join.pairs,
        )
    } else {
        frame_queries::cross_join_into(
            a.tree(),
            b.tree(),
            join.distance,
            join.mode,
            &mut join.workspace,
            &mut join.pairs,
        )
    };
    match result {
        // Only the distance can be wrong: no pairs until it is fixed, and
        // no join computed to count.
        Err(error) => {
            log::warn!("spatial join skipped: {error} (distance {})", join.distance);
            join.pairs.clear();
        }
        Ok(()) => {
            join.pairs.sort_unstable();
            sink.add(|d| d.joins.record(1, &mut join.workspace));
        }
    }
    report_changes(&join.previous, &join.pairs, &mut started, &mut ended);
}

/// Walks the two sorted pair lists once and reports what appeared and what
/// disappeared.
fn report_changes<A: Component, B: Component>(
    before: &[(Entity, Entity)],
    after: &[(Entity, Entity)],
    started: &mut MessageWriter<PairStarted<A, B>>,
    ended: &mut MessageWriter<PairEnded<A, B>>,
) {
    let (mut i, mut j) = (0, 0);
    while i < before.len() || j < after.len() {
        match (before.get(i), after.get(j)) {
            (Some(old), Some(new)) if old == new => {
                i += 1;
                j += 1;
            }
            (Some(old), Some(new)) if old < new => {
                ended.write(PairEnded::new(*old));
                i += 1;
            }
            (Some(_), Some(new)) | (None, Some(new)) => {
                started.write(PairStarted::new(*new));
                j += 1;
            }
            (Some(old), None) => {
                ended.write(PairEnded::new(*old));
                i += 1;
            }
            (None, None) => break,
        }
    }
}
