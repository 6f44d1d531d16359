//! Bad input gets a typed error, leaves the index unchanged, and causes no
//! panic later (SEMANTICS S2 and the bad-input hard cases).

mod common;

use bevy_rtree::{Aabb, ProxyId, QueryWorkspace, RTree, Ray, SpatialError, TreeSettings};
use glam::Vec3;

/// Everything observable about a tree: its length, what a query over the
/// whole world returns, and every entry's key and box.
type Snapshot = (usize, Vec<u32>, Vec<(u32, [f32; 6])>);

/// Everything observable about a tree, for before/after comparisons.
fn snapshot(tree: &RTree<u32>) -> Snapshot {
    let everything = Aabb::new(Vec3::splat(-1e15), Vec3::splat(1e15)).unwrap();
    let mut entries: Vec<(u32, [f32; 6])> = tree
        .iter()
        .map(|(_, k, b)| (k, [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z]))
        .collect();
    entries.sort_by_key(|e| e.0);
    (tree.len(), tree.overlapping(&everything), entries)
}

fn populated() -> (RTree<u32>, Vec<ProxyId>) {
    let mut tree = RTree::new();
    let ids = (0..300u32)
        .map(|i| {
            let p = Vec3::new((i % 17) as f32, (i / 17) as f32, 0.0);
            tree.insert(i, Aabb::new(p, p + Vec3::ONE).unwrap())
                .unwrap()
        })
        .collect();
    (tree, ids)
}

#[test]
fn invalid_boxes_are_refused_by_every_mutation() {
    let (mut tree, ids) = populated();
    let before = snapshot(&tree);
    for bad in common::invalid_boxes() {
        assert_eq!(
            tree.insert(999, bad),
            Err(SpatialError::InvalidBox),
            "{bad:?}"
        );
        assert_eq!(
            tree.update(ids[5], bad),
            Err(SpatialError::InvalidBox),
            "{bad:?}"
        );
        // A batch whose bad move comes after good ones moves nothing.
        let far = common::aabb([40.0; 3], [41.0; 3]);
        assert_eq!(
            tree.update_batch(&[(ids[1], far), (ids[2], far), (ids[3], bad)]),
            Err(SpatialError::InvalidBox),
            "{bad:?}"
        );
        let bulk = vec![(1000, common::aabb([0.0; 3], [1.0; 3])), (1001, bad)];
        assert_eq!(
            tree.insert_bulk(bulk.clone()),
            Err(SpatialError::InvalidBox),
            "{bad:?}"
        );
        assert_eq!(
            tree.insert_bulk_with_room(bulk.clone()),
            Err(SpatialError::InvalidBox),
            "{bad:?}"
        );
        let mut empty = RTree::<u32>::new();
        assert_eq!(
            empty.insert_bulk_with_room(bulk),
            Err(SpatialError::InvalidBox),
            "{bad:?}"
        );
        assert!(empty.is_empty());
        empty.validate().unwrap();
        tree.validate().unwrap();
        assert_eq!(snapshot(&tree), before);
    }
    // Nothing broke for later: the tree keeps working normally.
    tree.update(ids[5], common::aabb([50.0; 3], [51.0; 3]))
        .unwrap();
    tree.remove(ids[6]).unwrap();
    tree.validate().unwrap();
}

#[test]
fn invalid_queries_match_nothing_and_do_not_panic() {
    let (tree, _) = populated();
    let mut ws = QueryWorkspace::default();
    // Every entry of `populated` overlaps this box, so a query that ignored
    // the broken coordinate would match something.
    let everything = common::aabb([-1e6; 3], [1e6; 3]);
    assert!(!tree.overlapping(&everything).is_empty());
    let mut bad_queries = common::invalid_boxes();
    for axis in 0..3 {
        // Inverted on one axis only, within the first entry's extent there,
        // so that each comparison alone would pass for it.
        let mut inverted = everything;
        inverted.min[axis] = 0.75;
        inverted.max[axis] = 0.25;
        bad_queries.push(inverted);
    }
    for bad in bad_queries {
        assert!(tree.overlapping(&bad).is_empty(), "{bad:?}");
        assert!(!tree.any_overlapping(&bad, &mut ws), "{bad:?}");
    }
    for point in [Vec3::NAN, Vec3::INFINITY, Vec3::splat(2e15)] {
        assert!(tree.containing_point(point).is_empty(), "{point:?}");
    }
}

#[test]
fn unknown_and_stale_handles_are_refused() {
    let (mut tree, ids) = populated();
    let mut other = RTree::new();
    let foreign = (0..400u32)
        .map(|i| other.insert(i, common::aabb([0.0; 3], [1.0; 3])).unwrap())
        .last()
        .unwrap();
    let before = snapshot(&tree);
    assert_eq!(tree.remove(foreign), Err(SpatialError::UnknownProxy));
    assert_eq!(
        tree.update(foreign, common::aabb([0.0; 3], [1.0; 3])),
        Err(SpatialError::UnknownProxy)
    );
    let far = common::aabb([40.0; 3], [41.0; 3]);
    assert_eq!(
        tree.update_batch(&[(ids[1], far), (foreign, far)]),
        Err(SpatialError::UnknownProxy)
    );
    assert_eq!(snapshot(&tree), before);

    tree.remove(ids[0]).unwrap();
    let reused = tree.insert(77, common::aabb([0.0; 3], [1.0; 3])).unwrap();
    assert_eq!(reused.index(), ids[0].index(), "the slot is reused");
    assert_eq!(tree.remove(ids[0]), Err(SpatialError::UnknownProxy));
    assert_eq!(tree.get(ids[0]), Err(SpatialError::UnknownProxy));
    assert_eq!(tree.enlarged_box(ids[0]), Err(SpatialError::UnknownProxy));
    assert_eq!(tree.enlarged_box(foreign), Err(SpatialError::UnknownProxy));
    assert!(!tree.contains(ids[0]));
    let before = snapshot(&tree);
    assert_eq!(
        tree.update_batch(&[(ids[1], far), (ids[0], far)]),
        Err(SpatialError::UnknownProxy),
        "a stale handle in a batch"
    );
    assert_eq!(snapshot(&tree), before);
    assert_eq!(tree.get(reused).unwrap().0, 77);
    tree.validate().unwrap();
}

#[test]
fn a_handle_naming_a_free_slot_is_refused_whatever_its_generation() {
    let (mut tree, ids) = populated();
    let unit = common::aabb([0.0; 3], [1.0; 3]);
    // Another tree hands out slot 0 at generation 1: insert, remove, insert.
    let mut other = RTree::new();
    let first = other.insert(0u32, unit).unwrap();
    other.remove(first).unwrap();
    let foreign = other.insert(1, unit).unwrap();
    assert_eq!(foreign.index(), 0);

    // Here slot 0 is free at generation 1 after its entry's removal.
    assert_eq!(ids[0].index(), 0);
    tree.remove(ids[0]).unwrap();
    let before = snapshot(&tree);
    assert_eq!(tree.get(foreign), Err(SpatialError::UnknownProxy));
    assert_eq!(tree.update(foreign, unit), Err(SpatialError::UnknownProxy));
    assert_eq!(
        tree.update_batch(&[(ids[1], unit), (foreign, unit)]),
        Err(SpatialError::UnknownProxy)
    );
    assert_eq!(tree.remove(foreign), Err(SpatialError::UnknownProxy));
    assert_eq!(snapshot(&tree), before);
    tree.validate().unwrap();

    // After `clear`, no handle issued before it names anything.
    tree.clear();
    for &id in &ids {
        assert!(!tree.contains(id));
    }
    let fresh = tree.insert(9, unit).unwrap();
    assert!(ids.iter().all(|&old| old != fresh));
    assert_eq!(tree.get(fresh).unwrap().0, 9);
    tree.validate().unwrap();
}

#[test]
fn invalid_settings_are_refused() {
    let bad = [
        TreeSettings {
            margin: -1.0,
            ..TreeSettings::default()
        },
        TreeSettings {
            margin: f32::NAN,
            ..TreeSettings::default()
        },
        TreeSettings {
            margin_fraction: f32::INFINITY,
            ..TreeSettings::default()
        },
        TreeSettings {
            displacement_factor: -0.5,
            ..TreeSettings::default()
        },
        TreeSettings {
            repack_fraction: 0.0,
            ..TreeSettings::default()
        },
        TreeSettings {
            repack_fraction: f32::NAN,
            ..TreeSettings::default()
        },
        TreeSettings {
            repack_fraction: 16.5,
            ..TreeSettings::default()
        },
    ];
    for settings in bad {
        assert_eq!(
            RTree::<u32>::with_settings(settings).map(|_| ()),
            Err(SpatialError::InvalidSettings)
        );
    }
}

#[test]
fn bad_rays_are_typed_errors() {
    let cases = [
        Ray {
            origin: Vec3::ZERO,
            dir: Vec3::ZERO,
            max_t: 1.0,
        },
        Ray {
            origin: Vec3::NAN,
            dir: Vec3::X,
            max_t: 1.0,
        },
        Ray {
            origin: Vec3::ZERO,
            dir: Vec3::new(f32::INFINITY, 0.0, 0.0),
            max_t: 1.0,
        },
        Ray {
            origin: Vec3::ZERO,
            dir: Vec3::X,
            max_t: -1.0,
        },
        Ray {
            origin: Vec3::ZERO,
            dir: Vec3::X,
            max_t: f32::NAN,
        },
        Ray {
            origin: Vec3::ZERO,
            dir: Vec3::splat(1e-40),
            max_t: 1.0,
        },
    ];
    for ray in cases {
        assert_eq!(
            ray.canonicalized(),
            Err(SpatialError::InvalidRay),
            "{ray:?}"
        );
    }
    let subnormal = Ray::new(Vec3::ZERO, Vec3::new(1.0, -1e-40, -0.0), f32::INFINITY).unwrap();
    assert_eq!(
        subnormal.dir.to_array().map(f32::to_bits),
        [1f32.to_bits(), 0, 0]
    );
}

/// A query that fails leaves its caller's output as it was: the error is
/// found before the output is touched.
#[test]
fn failed_queries_leave_their_output_as_it_was() {
    let (tree, _) = populated();
    let mut ws = QueryWorkspace::default();
    let mut hits = Vec::new();
    let good = Ray::new(Vec3::new(-5.0, 0.5, 0.5), Vec3::X, 100.0).unwrap();
    tree.cast_ray_all(&good, None, &mut ws, &mut hits).unwrap();
    assert!(!hits.is_empty());
    let bad = Ray {
        origin: Vec3::new(-5.0, 0.5, 0.5),
        dir: Vec3::X,
        max_t: f32::NAN,
    };
    let before = hits.clone();
    assert_eq!(
        tree.cast_ray_all(&bad, None, &mut ws, &mut hits),
        Err(SpatialError::InvalidRay)
    );
    assert_eq!(hits, before);

    let mut near = Vec::new();
    tree.nearest_into(Vec3::ZERO, 3, None, &mut ws, &mut near)
        .unwrap();
    assert_eq!(near.len(), 3);
    let before = near.clone();
    assert_eq!(
        tree.nearest_into(Vec3::ZERO, 0, None, &mut ws, &mut near),
        Err(SpatialError::InvalidCount)
    );
    assert_eq!(
        tree.nearest_into(Vec3::NAN, 3, None, &mut ws, &mut near),
        Err(SpatialError::InvalidBox)
    );
    assert_eq!(
        tree.within_radius_into(Vec3::ZERO, -1.0, &mut ws, &mut near),
        Err(SpatialError::InvalidDistance)
    );
    assert_eq!(near, before);
}
