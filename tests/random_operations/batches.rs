//! The batched, filtered, cross-tree and parallel forms of the queries on
//! the tree as the random operations left it, against the oracle.

use super::*;

impl Model {
    /// The batched, filtered, cross-tree and (feature `parallel`) parallel
    /// forms of the queries on the tree as the mutations left it, against
    /// the oracle: a batch of rays sharing an origin (enough for the batch
    /// to answer them from one point query at that origin, often the middle
    /// of an entry) and one from elsewhere, now and then enough rays for the
    /// batched walk; a filter that drops every third key; the k nearest past
    /// the small-k path; a cross join with a fresh small tree on either side.
    pub(super) fn check_batches_and_filters(&mut self, point: Vec3, distance: f32) {
        let tree = &self.tree;
        let ws = &mut QueryWorkspace::default();
        // 9 rays share an origin (the batch takes 8 or more to answer from
        // one point query); 1,100 take the batched walk (1,024 or more).
        let sharing = if self.rng.below(16) == 0 { 1_100 } else { 9 };
        let mut rays = Vec::new();
        for _ in 0..sharing {
            let target = random_box(&mut self.rng, self.profile);
            let towards = ((target.min + target.max) * 0.5 - point).as_dvec3();
            let dir = (towards / towards.length()).as_vec3();
            let reach = [1e3, f32::INFINITY][self.rng.below(2)];
            rays.extend(Ray::new(point, dir, reach));
        }
        let other = random_box(&mut self.rng, self.profile);
        rays.extend(Ray::new(other.min, self.rng.direction(), f32::INFINITY));
        #[cfg(feature = "parallel")]
        let mut pws = bevy_rtree::ParallelWorkspace::default()
            .with_min_rays_per_task(1)
            .with_min_entries_to_split(0)
            .with_min_view_entries_to_split(0);
        for mode in [RayMode::First, RayMode::All { limit: None }] {
            let mut batch = RayResults::default();
            tree.cast_rays(&rays, mode, ws, &mut batch);
            assert_same_as_oracle(&batch, &rays, mode, &self.oracle);
            #[cfg(feature = "parallel")]
            {
                let mut split = RayResults::default();
                tree.par_cast_rays(&rays, mode, &mut pws, &mut split);
                assert_same_as_oracle(&split, &rays, mode, &self.oracle);
            }
        }
        #[cfg(feature = "parallel")]
        {
            let mut pairs = Vec::new();
            tree.par_self_join_into(distance, JoinMode::Euclidean, &mut pws, &mut pairs)
                .unwrap();
            pairs.sort_unstable();
            let all = self.oracle.self_join(distance, JoinMode::Euclidean);
            assert_eq!(Ok(pairs), all, "parallel self join at {distance}");
        }

        let allow = |key: u32| !key.is_multiple_of(3);
        let mut kept = BruteForce::default();
        for &(key, aabb) in self.oracle.entries() {
            if allow(key) {
                kept.insert(key, aabb);
            }
        }
        for ray in &rays {
            assert_eq!(tree.cast_ray_where(ray, ws, allow), kept.ray_first(ray));
            let mut hits = Vec::new();
            let all = tree.cast_ray_all_where(ray, None, ws, &mut hits, allow);
            assert_eq!(all.map(|()| hits), kept.ray_hits(ray));
        }
        for k in [1, 20] {
            let mut near = Vec::new();
            let found = tree.nearest_where_into(point, k, None, ws, &mut near, allow);
            assert_eq!(
                found.map(|()| near),
                kept.nearest(point, k, None),
                "k = {k}"
            );
        }
        assert_eq!(
            tree.nearest(point, 20, None),
            self.oracle.nearest(point, 20, None)
        );

        // A fresh small tree of the same profile, keys apart from the
        // model's, on either side of the cross join.
        let mut small = RTree::<u32>::new();
        let mut small_oracle = BruteForce::default();
        for i in 0..30 {
            let aabb = random_box(&mut self.rng, self.profile);
            small.insert(u32::MAX - i, aabb).unwrap();
            small_oracle.insert(u32::MAX - i, aabb);
        }
        for mode in [JoinMode::Euclidean, JoinMode::Chebyshev] {
            let want = self.oracle.cross_join(&small_oracle, distance, mode);
            assert_eq!(tree.cross_join(&small, distance, mode), want);
            let back = small_oracle.cross_join(&self.oracle, distance, mode);
            assert_eq!(small.cross_join(tree, distance, mode), back);
            #[cfg(feature = "parallel")]
            {
                let mut pws = bevy_rtree::ParallelWorkspace::default().with_min_entries_to_split(0);
                let mut pairs = Vec::new();
                let done = tree.par_cross_join_into(&small, distance, mode, &mut pws, &mut pairs);
                pairs.sort_unstable();
                assert_eq!(done.map(|()| pairs), want, "parallel cross join");
            }
        }
    }
}

/// Slot by slot, a batch's answers equal the oracle's for each ray alone:
/// the first hit, or every hit, or the same error.
fn assert_same_as_oracle(
    batch: &RayResults<u32>,
    rays: &[Ray],
    mode: RayMode,
    oracle: &BruteForce<u32>,
) {
    assert_eq!(batch.len(), rays.len());
    for (i, ray) in rays.iter().enumerate() {
        match mode {
            RayMode::First => assert_eq!(batch.first(i), oracle.ray_first(ray), "ray {i}"),
            _ => assert_eq!(
                batch.hits(i).map(<[_]>::to_vec),
                oracle.ray_hits(ray),
                "ray {i}"
            ),
        }
    }
}
