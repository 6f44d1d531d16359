//! What the plugin did this frame, so that cost (and its absence) can be
//! seen and tested without a profiler.

#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectResource;
#[cfg(feature = "reflect")]
use bevy_reflect::std_traits::ReflectDefault;
use std::sync::Mutex;

use bevy_ecs::prelude::*;

use super::frame_queries::FrameWorkspace;
use super::index::SyncCount;
use crate::query::QueryWorkspace;

/// Work done by one query family in one frame.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::prelude::*;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// let unit = Aabb::new(Vec3::ZERO, Vec3::ONE)?;
/// app.world_mut().spawn(SpatialBounds(unit));
/// let frustum = Frustum::perspective(Vec3::new(0.5, 0.5, 5.0), Quat::IDENTITY, 1.0, 1.5, 0.1, 100.0)?;
/// app.world_mut().spawn(CullingCamera::new(frustum));
/// app.update();
/// let d = app.world().resource::<SpatialDiagnostics>();
/// assert_eq!(d.sync.inserted, 1); // SyncWork
/// assert_eq!(d.culling.runs, 1); // QueryWork
/// assert!(d.culling.nodes_visited > 0);
/// assert_eq!(d.maintenance.runs, 0); // MaintenanceWork: nothing to repair yet
/// # Ok::<(), SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Debug, PartialEq, Clone))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct QueryWork {
    /// How many times the family's system ran: once per layer that has
    /// work (whatever modes its cameras or casters use), and once per join
    /// that is computed.
    pub runs: u32,
    /// Queries asked: cameras culled, rays cast (refused ones among them),
    /// joins computed.
    pub queries: u64,
    /// Tree nodes whose lanes were tested.
    pub nodes_visited: u64,
    /// Leaf lanes tested (see [`QueryStats::entries_tested`](crate::QueryStats)).
    pub entries_tested: u64,
    /// Queries refused as invalid this frame, counted every frame they
    /// stay refused and logged once each time they become so: a caster
    /// whose ray is not valid in world space (a zero scale, a NaN
    /// transform; its `RayCasterHits` holds the error), a followed Bevy
    /// frustum the crate refuses (the camera keeps its last frustum).
    pub refused: u64,
}

impl QueryWork {
    /// Adds one run's statistics, taken from its workspace.
    pub(crate) fn record(&mut self, queries: usize, workspace: &mut FrameWorkspace) {
        // Both workspaces (one thread or a task per thread) sum their own.
        self.add(queries, workspace.take_stats());
    }

    /// Adds one run's statistics, summed over the workspaces of its
    /// queries (one each where they ran in parallel).
    #[cfg_attr(not(feature = "bevy_camera"), allow(dead_code))]
    pub(crate) fn record_workspaces(&mut self, queries: usize, workspaces: &mut [QueryWorkspace]) {
        self.add(queries, crate::QueryStats::default());
        for ws in workspaces {
            self.add_walks(ws);
        }
    }

    /// Adds the work of walks made for queries already counted (a
    /// caster's ray cast again through its filter), without a run.
    pub(crate) fn add_walks(&mut self, workspace: &mut QueryWorkspace) {
        let stats = workspace.take_stats();
        self.nodes_visited += stats.nodes_visited;
        self.entries_tested += stats.entries_tested;
    }

    fn add(&mut self, queries: usize, stats: crate::QueryStats) {
        self.runs += 1;
        self.queries += queries as u64;
        self.nodes_visited += stats.nodes_visited;
        self.entries_tested += stats.entries_tested;
    }
}

/// How the indexes followed the entities this frame, summed over layers.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::prelude::*;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// let unit = Aabb::new(Vec3::ZERO, Vec3::ONE)?;
/// app.world_mut().spawn(SpatialBounds(unit));
/// let frustum = Frustum::perspective(Vec3::new(0.5, 0.5, 5.0), Quat::IDENTITY, 1.0, 1.5, 0.1, 100.0)?;
/// app.world_mut().spawn(CullingCamera::new(frustum));
/// app.update();
/// let d = app.world().resource::<SpatialDiagnostics>();
/// assert_eq!(d.sync.inserted, 1); // SyncWork
/// assert_eq!(d.sync.runs, 2); // the startup sync's pass and this frame's
/// assert_eq!(d.culling.runs, 1); // QueryWork
/// assert!(d.culling.nodes_visited > 0);
/// assert_eq!(d.maintenance.runs, 0); // MaintenanceWork: nothing to repair yet
/// # Ok::<(), SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Debug, PartialEq, Clone))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SyncWork {
    /// Sync passes that ran (one per layer with indexed entities or changes;
    /// the first frame's figures also hold the startup sync's pass, which
    /// indexes the entities spawned before it, so they count two).
    pub runs: u32,
    /// Entities that entered an index.
    pub inserted: u64,
    /// Entities whose box changed in an index.
    pub updated: u64,
    /// Entities that left an index (despawn, component or marker removed,
    /// opt-out, invalid box).
    pub removed: u64,
    /// Entities skipped because their box was invalid (see
    /// [`SpatialBounds`](super::SpatialBounds)).
    pub invalid_skipped: u64,
}

/// Repairs of degraded leaves this frame.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::prelude::*;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// let unit = Aabb::new(Vec3::ZERO, Vec3::ONE)?;
/// app.world_mut().spawn(SpatialBounds(unit));
/// let frustum = Frustum::perspective(Vec3::new(0.5, 0.5, 5.0), Quat::IDENTITY, 1.0, 1.5, 0.1, 100.0)?;
/// app.world_mut().spawn(CullingCamera::new(frustum));
/// app.update();
/// let d = app.world().resource::<SpatialDiagnostics>();
/// assert_eq!(d.sync.inserted, 1); // SyncWork
/// assert_eq!(d.culling.runs, 1); // QueryWork
/// assert!(d.culling.nodes_visited > 0);
/// assert_eq!(d.maintenance.runs, 0); // MaintenanceWork: nothing to repair yet
/// # Ok::<(), SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Debug, PartialEq, Clone))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MaintenanceWork {
    /// Maintenance passes that ran (only where a layer had something to
    /// repair, a rebuild to start or advance, or a rebuild's work out on the
    /// task pool).
    pub runs: u32,
    /// Nodes re-tiled.
    pub nodes_repacked: u64,
    /// Rebuilds swapped in (see `SpatialIndexPlugin::rebuild`).
    pub rebuilds: u32,
}

/// How `BevyVisibilityPlugin` decided its cameras this frame: what the
/// tree proved and what it left to Bevy's own tests. Zero without the
/// plugin (feature `bevy_camera`).
///
/// ```
/// use bevy_rtree::plugin::BevyVisibilityWork;
///
/// let work = BevyVisibilityWork { candidates: 100, proven: 90, tested: 12 };
/// // 10 candidates and 2 entities outside the tree took Bevy's tests.
/// assert_eq!(work.candidates - work.proven, 10);
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Debug, PartialEq, Clone))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BevyVisibilityWork {
    /// The tree's candidates, summed over the cameras that cull.
    pub candidates: u64,
    /// Candidates the tree proved inside every plane Bevy tests: they skip
    /// Bevy's frustum tests.
    pub proven: u64,
    /// Entity-camera pairs left to Bevy's own checks one by one: the
    /// candidates not proven, and the entities outside the tree (no
    /// `Aabb`, `NoFrustumCulling`, an unusable box) for every camera that
    /// culls. Some of them stop at Bevy's first checks (hidden, another
    /// layer) before any frustum test.
    pub tested: u64,
}

/// Per-frame counters of what the plugin ran, published at the end of every
/// frame (in `Last`): read them after the frame, or in the next one.
///
/// A scene that has no culling camera shows `culling.runs == 0`, one without
/// casters `rays.runs == 0`, and so on: the plugin only does the work a scene
/// calls for.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::plugin::{SpatialDiagnostics, SpatialIndexPlugin};
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// app.update();
/// let diagnostics = app.world().resource::<SpatialDiagnostics>();
/// assert_eq!(diagnostics.culling.runs, 0);
/// assert_eq!(diagnostics.rays.runs, 0);
/// assert_eq!(diagnostics.joins.runs, 0);
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(
    feature = "reflect",
    reflect(Resource, Default, Debug, PartialEq, Clone)
)]
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SpatialDiagnostics {
    /// Frames since the plugin was added.
    pub frame: u64,
    /// Index updates.
    pub sync: SyncWork,
    /// Leaf repairs.
    pub maintenance: MaintenanceWork,
    /// Frustum culling for [`CullingCamera`](super::CullingCamera)s.
    pub culling: QueryWork,
    /// Batched raycasts for [`RayCaster`](super::RayCaster)s.
    pub rays: QueryWork,
    /// Registered spatial joins.
    pub joins: QueryWork,
    /// Bevy's camera visibility served by the index.
    pub bevy_visibility: BevyVisibilityWork,
    /// Invalid-box skips since the plugin was added (never reset).
    pub invalid_total: u64,
}

impl SpatialDiagnostics {
    pub(crate) fn record_sync(&mut self, count: &SyncCount) {
        self.sync.runs += 1;
        self.sync.inserted += count.inserted;
        self.sync.updated += count.updated;
        self.sync.removed += count.removed;
        self.sync.invalid_skipped += count.invalid;
        self.invalid_total += count.invalid;
    }
}

/// Where the plugin's systems and observers add their counts during a frame.
///
/// Systems share it read-only (the lock is held for a few additions), so
/// counting does not force the systems of different layers and query
/// families to run one after the other.
#[derive(Resource, Default)]
pub(crate) struct DiagnosticsSink(Mutex<SpatialDiagnostics>);

impl DiagnosticsSink {
    pub(crate) fn add(&self, count: impl FnOnce(&mut SpatialDiagnostics)) {
        // A panic elsewhere while holding the lock leaves plain counters
        // behind, which are still fine to add to.
        let mut frame = self
            .0
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        count(&mut frame);
    }
}

/// Publishes the frame's counts (in `Last`) and starts the next frame.
pub(crate) fn publish_diagnostics(
    sink: Res<DiagnosticsSink>,
    mut diagnostics: ResMut<SpatialDiagnostics>,
) {
    let mut frame = SpatialDiagnostics::default();
    sink.add(|counted| frame = std::mem::take(counted));
    *diagnostics = SpatialDiagnostics {
        frame: diagnostics.frame + 1,
        invalid_total: diagnostics.invalid_total + frame.invalid_total,
        ..frame
    };
}
