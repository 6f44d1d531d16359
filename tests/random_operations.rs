//! Long random operation sequences over extreme coordinate profiles, each
//! step followed by `validate()`, the repair queue's bound and every query
//! family against the oracle, so that the next defect of the kind
//! adversarial testing found (a panic at `f32::MAX`, a queue that grew) is
//! found here first.
//!
//! `cargo test --test random_operations` runs a short soak (seconds);
//! `cargo test --release --test random_operations -- --ignored` runs one
//! fifty times longer (about a minute).

use std::collections::BTreeMap;
use std::ops::ControlFlow;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::SceneRng;
use bevy_rtree::{
    Aabb, CullMode, Frustum, HalfSpace, JoinMode, MAX_COORD, ProxyId, QueryWorkspace, RTree, Ray,
    RayMode, RayResults, RebuildWork, SpatialError, TreeSettings,
};
use glam::{Quat, Vec3};

/// Where a profile puts its boxes.
#[derive(Clone, Copy, Debug)]
enum Profile {
    /// A dyadic grid near the origin: faces coincide, boxes touch.
    Grid,
    /// The standard world's scale, 0 to 2 km.
    Town,
    /// A town a million metres out.
    FarOut,
    /// Near `±MAX_COORD`, sizes from a point to 1e14.
    AtTheLimit,
    /// Subnormal-scale coordinates and sizes.
    Tiny,
    /// Each box from any profile.
    Mixed,
}

const PROFILES: [Profile; 6] = [
    Profile::Grid,
    Profile::Town,
    Profile::FarOut,
    Profile::AtTheLimit,
    Profile::Tiny,
    Profile::Mixed,
];

/// A random valid box of `profile`.
fn random_box(rng: &mut SceneRng, profile: Profile) -> Aabb {
    let profile = match profile {
        Profile::Mixed => PROFILES[rng.below(5)],
        other => other,
    };
    let (min, size) = match profile {
        Profile::Grid => {
            let cell = |rng: &mut SceneRng| (rng.below(33) as f32 - 16.0) * 0.25;
            let min = Vec3::new(cell(rng), cell(rng), cell(rng));
            let size = Vec3::new(
                rng.below(5) as f32,
                rng.below(5) as f32,
                rng.below(5) as f32,
            );
            (min, size * 0.25)
        }
        Profile::Town | Profile::FarOut => {
            let offset = if matches!(profile, Profile::FarOut) {
                1e6
            } else {
                0.0
            };
            let min = Vec3::new(
                rng.range(0.0, 2000.0),
                rng.range(0.0, 100.0),
                rng.range(0.0, 2000.0),
            );
            (min + offset, Vec3::splat(rng.range(0.0, 20.0)))
        }
        Profile::AtTheLimit => {
            let edge = |rng: &mut SceneRng| {
                let sign = if rng.below(2) == 0 { 1.0 } else { -1.0 };
                sign * MAX_COORD * rng.range(0.9, 1.0)
            };
            let min = Vec3::new(edge(rng), edge(rng), edge(rng));
            let size = [0.0, 1.0, 1e6, 1e14][rng.below(4)];
            (min, Vec3::splat(size))
        }
        Profile::Tiny => {
            let coord = |rng: &mut SceneRng| rng.range(-1.0, 1.0) * 1e-38;
            (
                Vec3::new(coord(rng), coord(rng), coord(rng)),
                Vec3::splat(1e-39),
            )
        }
        Profile::Mixed => unreachable!("resolved above"),
    };
    let min = min.clamp(Vec3::splat(-MAX_COORD), Vec3::splat(MAX_COORD));
    let max = (min + size).min(Vec3::splat(MAX_COORD));
    Aabb::new(min, max).expect("profiles make valid boxes")
}

/// The tree, the oracle and the handle of each live key, kept in step.
struct Model {
    tree: RTree<u32>,
    oracle: BruteForce<u32>,
    handles: BTreeMap<u32, ProxyId>,
    next_key: u32,
    profile: Profile,
    rng: SceneRng,
    /// How often each checked family had a non-empty answer: box overlap,
    /// point, first hit, a view, the self join (a run whose answers were
    /// all empty would check little).
    answered: [usize; 5],
    /// A rebuild's work taken out of the tree (as if on another thread),
    /// run or not yet, while the tree answers and changes.
    away: Option<RebuildWork<u32>>,
    /// Works that came back and were accepted.
    came_back: usize,
}

impl Model {
    fn pick(&mut self) -> Option<(u32, ProxyId)> {
        let n = self.handles.len();
        (n > 0).then(|| {
            let i = self.rng.below(n);
            let (k, h) = self.handles.iter().nth(i).unwrap();
            (*k, *h)
        })
    }

    fn insert(&mut self, aabb: Aabb) {
        let key = self.next_key;
        self.next_key += 1;
        let id = self.tree.insert(key, aabb).unwrap();
        self.oracle.insert(key, aabb);
        self.handles.insert(key, id);
    }

    fn move_to(&mut self, key: u32, id: ProxyId, aabb: Aabb) {
        self.tree.update(id, aabb).unwrap();
        self.oracle.update(key, aabb);
    }

    /// One random mutation, or a refused one that must change nothing.
    fn step(&mut self) {
        let profile = self.profile;
        match self.rng.below(25) {
            0..=4 => {
                let aabb = random_box(&mut self.rng, profile);
                self.insert(aabb);
            }
            5..=8 => {
                if let Some((key, id)) = self.pick() {
                    let (_, old) = self.tree.get(id).unwrap();
                    let step = (old.extent() + 1e-30) * self.rng.range(-0.3, 0.3);
                    if let Ok(moved) = Aabb::new(old.min + step, old.max + step) {
                        self.move_to(key, id, moved);
                    }
                }
            }
            9..=10 => {
                if let Some((key, id)) = self.pick() {
                    let teleported = random_box(&mut self.rng, profile);
                    self.move_to(key, id, teleported);
                }
            }
            11..=13 => {
                if let Some((key, id)) = self.pick() {
                    assert_eq!(self.tree.remove(id), Ok(key));
                    self.oracle.remove(key);
                    self.handles.remove(&key);
                    assert_eq!(self.tree.remove(id), Err(SpatialError::UnknownProxy));
                }
            }
            14 => {
                let boxes: Vec<Aabb> = (0..self.rng.below(40))
                    .map(|_| random_box(&mut self.rng, profile))
                    .collect();
                let first = self.next_key;
                self.next_key += boxes.len() as u32;
                let keyed = boxes
                    .iter()
                    .enumerate()
                    .map(|(i, b)| (first + i as u32, *b));
                // Leaves packed full, or with room, by the batch's length.
                let ids = if boxes.len().is_multiple_of(2) {
                    self.tree.insert_bulk(keyed).unwrap()
                } else {
                    self.tree.insert_bulk_with_room(keyed).unwrap()
                };
                for (i, (aabb, id)) in boxes.iter().zip(ids).enumerate() {
                    self.oracle.insert(first + i as u32, *aabb);
                    self.handles.insert(first + i as u32, id);
                }
            }
            15 => {
                let budget = [0, 1, 64, usize::MAX][self.rng.below(4)];
                self.tree.optimize(budget);
            }
            16 => {
                if self.rng.below(4) == 0 {
                    self.tree.rebuild();
                }
            }
            20 => self.tree.start_rebuild(),
            21 => {
                // A slice of the rebuild under way (a swap when it
                // completes).
                let units = [1, 3, 10, usize::MAX][self.rng.below(4)];
                self.tree.step_rebuild_units(units);
            }
            22 => {
                if self.rng.below(6) == 0 {
                    self.tree.cancel_rebuild();
                } else {
                    self.tree.step_rebuild_units(1);
                }
            }
            23 => {
                // The rebuild's work goes out, run at once or later.
                if self.away.is_none() {
                    if !self.tree.rebuild_pending() {
                        self.tree.start_rebuild();
                    }
                    self.away = self.tree.take_rebuild_work();
                    if self.rng.below(2) == 0
                        && let Some(work) = &mut self.away
                    {
                        work.run();
                    }
                }
            }
            24 => {
                // The work comes back: accepted if its rebuild is still the
                // one under way (not dropped meanwhile by a bulk insert, a
                // `rebuild`, a clear or a cancel).
                if let Some(mut work) = self.away.take() {
                    work.run();
                    let pending = self.tree.rebuild_pending();
                    let accepted = self.tree.finish_rebuild_work(work);
                    assert!(!accepted || pending);
                    self.came_back += usize::from(accepted);
                }
            }
            17 => {
                // Invalid input: refused, and nothing changes.
                let bad = [
                    Aabb {
                        min: Vec3::ONE,
                        max: Vec3::ZERO,
                    },
                    Aabb {
                        min: Vec3::ZERO,
                        max: Vec3::new(2e15, 1.0, 1.0),
                    },
                    Aabb {
                        min: Vec3::NAN,
                        max: Vec3::ONE,
                    },
                ][self.rng.below(3)];
                let len = self.tree.len();
                assert_eq!(
                    self.tree.insert(u32::MAX, bad),
                    Err(SpatialError::InvalidBox)
                );
                if let Some((_, id)) = self.pick() {
                    assert_eq!(self.tree.update(id, bad), Err(SpatialError::InvalidBox));
                }
                assert_eq!(self.tree.len(), len);
            }
            _ => {
                // Remove and reinsert in one frame; the old handle dies.
                if let Some((key, id)) = self.pick() {
                    let (_, aabb) = self.tree.get(id).unwrap();
                    self.tree.remove(id).unwrap();
                    let again = self.tree.insert(key, aabb).unwrap();
                    assert!(!self.tree.contains(id));
                    self.handles.insert(key, again);
                }
            }
        }
    }

    /// Invariants, the repair queue's bound, live handles and every query
    /// family.
    fn check(&mut self) {
        let moved: Vec<(u32, ProxyId)> = (0..3).filter_map(|_| self.pick()).collect();
        let tree = &self.tree;
        tree.validate().unwrap();
        for &(key, id) in &moved {
            let box_now = self.oracle.entries().iter().find(|e| e.0 == key).unwrap().1;
            assert_eq!(tree.get(id), Ok((key, box_now)), "handle of {key}");
        }
        assert_eq!(tree.len(), self.oracle.len());
        assert!(
            tree.pending_repairs() <= tree.nodes_at_level(1),
            "{} repairs queued for {} level-1 nodes",
            tree.pending_repairs(),
            tree.nodes_at_level(1)
        );
        let ws = &mut QueryWorkspace::default();
        let query = random_box(&mut self.rng, self.profile);
        let grown = query.grown(query.extent() + 1.0);
        for q in [query, grown] {
            assert_eq!(tree.overlapping(&q), self.oracle.overlapping(&q));
        }
        self.answered[0] += usize::from(!self.oracle.overlapping(&grown).is_empty());
        // A corner of the query, or the middle of a live entry (which holds
        // it): a point that hits something now and then.
        let entries = self.oracle.entries();
        let point = if self.rng.below(2) == 0 || entries.is_empty() {
            query.min
        } else {
            let (_, inside) = entries[self.rng.below(entries.len())];
            (inside.min + inside.max) * 0.5
        };
        let at_point = self.oracle.containing_point(point);
        assert_eq!(tree.containing_point(point), at_point);
        self.answered[1] += usize::from(!at_point.is_empty());

        // Towards the middle of a random box, with a unit direction (worked
        // out in f64, so that the Tiny profile's subnormal offsets give a
        // valid ray) and the segment's length in metres.
        let target = random_box(&mut self.rng, self.profile);
        let towards = ((target.min + target.max) * 0.5 - point).as_dvec3();
        let distance = towards.length();
        let reach = [1.0, 3.0, f64::INFINITY][self.rng.below(3)] * distance;
        if let Ok(ray) = Ray::new(point, (towards / distance).as_vec3(), reach as f32) {
            let first = self.oracle.ray_first(&ray);
            assert_eq!(tree.cast_ray(&ray, ws), first);
            self.answered[2] += usize::from(matches!(first, Ok(Some(_))));
            let mut hits = Vec::new();
            let all = tree.cast_ray_all(&ray, None, ws, &mut hits);
            assert_eq!(all.map(|()| hits), self.oracle.ray_hits(&ray));
        }

        let eye = point.clamp(Vec3::splat(-MAX_COORD), Vec3::splat(MAX_COORD));
        let turn = Quat::from_rotation_y(self.rng.range(0.0, 6.3));
        let far = [10.0, 1e9, f32::INFINITY][self.rng.below(3)];
        let mut views = vec![Frustum::perspective(eye, turn, 1.2, 1.5, 0.05, far).unwrap()];
        let normal = self.rng.direction();
        let slab = HalfSpace {
            normal,
            offset: 1e30,
        };
        let side = HalfSpace {
            normal: -normal,
            offset: 5.0,
        };
        let i = HalfSpace::INACTIVE;
        views.extend(Frustum::new(eye, [slab, side, i, i, i, i]));
        for view in &views {
            for mode in [CullMode::Conservative, CullMode::Exact] {
                let seen = self.oracle.visible(view, mode);
                assert_eq!(tree.visible(view, mode), seen);
                self.answered[3] += usize::from(!seen.is_empty());
            }
        }

        // Distances that join nearly every pair (tens of thousands of
        // pairs, each answer sorted) one check in four: at one in two,
        // sorting them took most of the test's time.
        let distance = match self.rng.below(8) {
            0 => 1e3,
            1 => f32::MAX,
            k => [0.0, 0.5][k % 2],
        };
        for mode in [JoinMode::Euclidean, JoinMode::Chebyshev] {
            let all = self.oracle.self_join(distance, mode).unwrap();
            assert_eq!(tree.self_join(distance, mode).unwrap(), all);
            self.answered[4] += usize::from(!all.is_empty());
            let ids: Vec<ProxyId> = moved.iter().map(|m| m.1).collect();
            let mut got = Vec::new();
            tree.visit_self_join_moved(&ids, distance, mode, ws, |a, b| {
                got.push((a, b));
                ControlFlow::Continue(())
            })
            .unwrap();
            got.sort_unstable();
            let keys: Vec<u32> = moved.iter().map(|m| m.0).collect();
            let want: Vec<(u32, u32)> = all
                .into_iter()
                .filter(|(a, b)| keys.contains(a) || keys.contains(b))
                .collect();
            assert_eq!(got, want, "moved join of {keys:?} at {distance}");
        }
        let radius = [0.0, 1.0, 1e6, f32::MAX][self.rng.below(4)];
        assert_eq!(
            tree.within_radius(point, radius),
            self.oracle.within_radius(point, radius)
        );
        let nearest = self.oracle.nearest(point, 4, None);
        assert_eq!(tree.nearest(point, 4, None), nearest);
        // A radius and a limit exactly at the fourth nearest entry's
        // distance (rounded up to `f32`): at the boundary, in a pruned
        // tree, at every profile's magnitudes.
        if let Ok(found) = &nearest
            && let Some(last) = found.last()
        {
            let exact = last.distance();
            let at = exact as f32;
            let at = if f64::from(at) < exact {
                at.next_up()
            } else {
                at
            };
            let within = self.oracle.within_radius(point, at);
            assert!(
                within
                    .as_ref()
                    .is_ok_and(|w| w.iter().any(|n| n.key == last.key))
            );
            assert_eq!(tree.within_radius(point, at), within, "radius {at}");
            assert_eq!(
                tree.nearest(point, 8, Some(at)),
                self.oracle.nearest(point, 8, Some(at)),
                "limit {at}"
            );
        }
        // The sorted form, and the visit order of the `_into` form sorted.
        let in_sphere = self.oracle.overlapping_sphere(point, radius);
        assert_eq!(tree.overlapping_sphere(point, radius), in_sphere);
        let mut sphere = Vec::new();
        let found = tree.overlapping_sphere_into(point, radius, ws, &mut sphere);
        sphere.sort_unstable();
        assert_eq!(found.map(|()| sphere), in_sphere);
        // One check in four: the batches, filters and parallel splits
        // cost as much again as the rest.
        if self.rng.below(4) == 0 {
            self.check_batches_and_filters(point, distance);
        }
    }
}

/// `steps` random steps per profile (more if no rebuild was swapped in by
/// then), checked after each.
fn soak(steps: usize, seed: u64) {
    for (p, profile) in PROFILES.into_iter().enumerate() {
        let settings = TreeSettings {
            // Repack often, so the repair queue is busy.
            repack_fraction: [0.25, f32::MIN_POSITIVE][p % 2],
            ..TreeSettings::default()
        };
        let mut model = Model {
            tree: RTree::with_settings(settings).unwrap(),
            oracle: BruteForce::default(),
            handles: BTreeMap::new(),
            next_key: 0,
            profile,
            rng: SceneRng::new(seed + p as u64),
            answered: [0; 5],
            away: None,
            came_back: 0,
        };
        let mut swaps = 0;
        // On until a rebuild was swapped in, up to four times the steps:
        // in a short run, the operations that drop a rebuild under way (a
        // bulk insert, `rebuild`, a clear, a cancel) can drop every one.
        for step in 0..steps * 4 {
            if step >= steps && swaps > 0 {
                break;
            }
            model.step();
            swaps += model.tree.take_maintenance_stats().rebuilds;
            // Keep the size around a few hundred entries.
            if model.handles.len() > 400 {
                model.tree.clear();
                model.oracle = BruteForce::default();
                model.handles.clear();
            }
            if std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| model.check())).is_err() {
                panic!("{profile:?}, seed {seed}, step {step}: see the failure above");
            }
        }
        // Rebuilds were swapped in among the other operations, and work
        // taken out came back to be swapped in.
        assert!(swaps >= 1, "{profile:?}: {swaps} rebuilds swapped in");
        assert!(model.came_back >= 1, "{profile:?}: no work came back");
        let answered = model.answered;
        assert!(
            answered.iter().all(|&n| n > 0),
            "{profile:?}: non-empty answers per family {answered:?}"
        );
    }
}

#[test]
fn random_operations_over_extreme_profiles_match_the_oracle() {
    soak(250, 1);
}

#[test]
#[ignore = "a minute in release: the long soak"]
fn a_long_soak_over_extreme_profiles_matches_the_oracle() {
    for seed in 100..110 {
        soak(1_250, seed);
    }
}

#[path = "random_operations/batches.rs"]
mod batches;
