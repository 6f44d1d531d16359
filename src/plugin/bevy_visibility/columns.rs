//! One table's (or one batch's) columns of Bevy's culling query, as a
//! contiguous query hands them over, and Bevy's decision for one row of
//! them: the same checks, in the same order, as `cameras::decide` makes for
//! one entity through `Query::get`. The look-ups by row (`rows.rs`) and the
//! pass in storage order (`storage_order.rs`) both decide through it.

use std::panic::Location;

use bevy_camera::primitives::{Aabb as BevyAabb, Sphere};
use bevy_camera::visibility::{
    InheritedVisibility, RenderLayers, SetViewVisibility, ViewVisibility, VisibilityClass,
    VisibleEntityRanges,
};
use bevy_ecs::change_detection::{ContiguousComponentTicksMut, ContiguousMut, MaybeLocation, Tick};
use bevy_ecs::prelude::*;
use bevy_ecs::query::ContiguousQueryData;
use bevy_transform::prelude::GlobalTransform;

use super::cameras::{Culled, Sight, may_be_seen, passes_frustum};
use super::seen::Seen;
use crate::tree::prefetch::prefetch_lines;

/// Whether the passes split over several threads may read Bevy's tables
/// in runs of rows (`contiguous_par_iter`), or must go row by row through
/// Bevy's `par_iter`.
///
/// Bevy 0.20.1 hands each batch of a parallel contiguous query the rows of
/// its run together with all of its table's entities, and its fetches of
/// `&T`, `&mut T` and `Ref<T>` check with `debug_assert_eq!` that the two
/// have one length: any batch smaller than its table panics in a build
/// with bevy_ecs's debug assertions on (a game's usual development build,
/// where `multi_threaded` is on by default). The rows themselves are the
/// right ones (the entities are cut to the run), so an optimized build
/// reads them by table; a debug build, whose profile gives bevy_ecs the
/// same assertions as this crate, goes row by row.
pub(super) const TABLES_SPLIT_ACROSS_THREADS: bool = !cfg!(debug_assertions);

/// The columns of [`Culled`] for a run of rows; row `i` of every column is
/// the entity `ids[i]`.
pub(super) struct CulledColumns<'w> {
    pub(super) ids: &'w [Entity],
    inherited: &'w [InheritedVisibility],
    view: &'w mut [ViewVisibility],
    ticks: ContiguousComponentTicksMut<'w>,
    class: Option<&'w [VisibilityClass]>,
    layers: Option<&'w [RenderLayers]>,
    aabbs: Option<&'w [BevyAabb]>,
    spheres: Option<&'w [Sphere]>,
    transforms: &'w [GlobalTransform],
    /// The run's entities have `NoFrustumCulling`.
    unculled: bool,
    /// The run's entities have a `VisibilityRange`.
    has_range: bool,
}

impl<'w> CulledColumns<'w> {
    /// The columns a contiguous query of [`Culled`] hands over, the
    /// visibility values apart from their change ticks (written by
    /// [`Self::decide`] only where Bevy's `set_visible` would write them).
    pub(super) fn new(
        columns: <Culled<'static> as ContiguousQueryData>::Contiguous<'w, '_>,
    ) -> Self {
        let (ids, inherited, view, class, layers, aabbs, spheres, transforms, unculled, has_range) =
            columns;
        let (view, ticks) = ContiguousMut::bypass_change_detection_split(view);
        CulledColumns {
            ids,
            inherited,
            view,
            ticks,
            class,
            layers,
            aabbs,
            spheres,
            transforms,
            unculled,
            has_range,
        }
    }

    /// Bevy's decision for `entity`, the one in `row`, and one view: Bevy's
    /// checks before any frustum test, then (unless the tree `proven` it
    /// inside every plane) Bevy's frustum tests; if it passes,
    /// `set_visible` and the view's lists by visibility class. (The caller
    /// has the entity at hand: reading it again from `ids` would be one
    /// more cache miss a candidate on the look-ups' path.)
    #[allow(clippy::too_many_arguments)]
    pub(super) fn decide(
        &mut self,
        row: usize,
        entity: Entity,
        sight: &Sight,
        seen: &mut Seen,
        proven: bool,
        ranges: Option<&VisibleEntityRanges>,
    ) {
        let mask = self.layers.map(|layers| &layers[row]);
        if !may_be_seen(
            sight,
            entity,
            &self.inherited[row],
            mask,
            self.has_range,
            ranges,
        ) {
            return;
        }
        if !proven {
            let aabb = self.aabbs.map(|aabbs| &aabbs[row]);
            let sphere = self.spheres.map(|spheres| &spheres[row]);
            if !passes_frustum(sight, aabb, sphere, &self.transforms[row], self.unculled) {
                return;
            }
        }
        self.set_visible(row);
        seen.push_classes(entity, self.class.map(|class| &class[row]));
    }

    /// Asks for the lines a proven decision on `row` reads.
    pub(super) fn prefetch_proven(&self, row: usize) {
        prefetch_lines(&self.inherited[row]);
        prefetch_lines(&self.view[row]);
        if let Some(class) = self.class {
            prefetch_lines(&class[row]);
        }
    }

    /// Bevy's `set_visible` on `row`: the value changed as Bevy changes it,
    /// and the row's change tick (and caller, where Bevy tracks it) written
    /// exactly when Bevy's would be.
    pub(super) fn set_visible(&mut self, row: usize) {
        let ticks = &mut self.ticks;
        let (last_run, this_run) = (ticks.last_run(), ticks.this_run());
        let mut value = self.view[row];
        // `set_visible` reads neither tick; the copy's changed tick becomes
        // `this_run` exactly when it marks the value changed. (The column
        // has no summary tick for it to update: `ViewVisibility` keeps
        // none, which a test checks.)
        let mut added = this_run;
        let mut changed = Tick::new(this_run.get().wrapping_sub(1));
        let mut caller = Location::caller();
        let mut visibility = Mut::new(
            &mut value,
            &mut added,
            &mut changed,
            None,
            last_run,
            this_run,
            MaybeLocation::new_with(|| &mut caller),
        );
        visibility.set_visible();
        let marked = changed == this_run;
        self.view[row] = value;
        if marked {
            ticks.changed_mut()[row] = this_run;
            ticks.changed_by_mut().map(|by| by[row] = caller);
        }
    }
}
