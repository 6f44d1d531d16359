//! The standard scene "town": deterministic from a seed, shared by the
//! examples, the benchmarks and the tests.
//!
//! 100,000 boxes in a 2000 x 100 x 2000 m world: 70 % in 200 Gaussian
//! clusters (sigma 30 m in x and z), 30 % uniform; half extents per axis
//! 70 % in [0.25, 1] m, 25 % in [1, 5] m, 5 % in [5, 25] m. Each entity has a
//! fixed step per frame, uniform in [-0.1, 0.1] m per axis; each frame a fresh
//! random 10 % move by their step and bounce off the world's edges.

use glam::{EulerRot, Quat, Vec3};

use crate::geometry::{Aabb, Frustum, Ray};
use crate::tree::{ProxyId, RTree};

/// Extent of the world: x and z in `[0, 2000]` m, y in `[0, 100]` m.
pub const WORLD_MAX: Vec3 = Vec3::new(2000.0, 100.0, 2000.0);

/// A small, fast, seedable generator (SplitMix64); good enough for scenes,
/// and it keeps the crate free of a random-number dependency.
#[derive(Clone, Debug)]
pub struct SceneRng(u64);

impl SceneRng {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        SceneRng(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform integer in `0..n` (`n > 0`).
    pub fn below(&mut self, n: usize) -> usize {
        (((self.next_u64() >> 32) * n as u64) >> 32) as usize
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f32 {
        let u1 = (1.0 - self.unit()).max(f32::MIN_POSITIVE);
        let u2 = self.unit();
        (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
    }

    /// Uniform point of the standard scene's world, `[0, WORLD_MAX)`
    /// (coordinates drawn x, then y, then z).
    pub fn point_in_world(&mut self) -> Vec3 {
        let x = self.range(0.0, WORLD_MAX.x);
        let y = self.range(0.0, WORLD_MAX.y);
        let z = self.range(0.0, WORLD_MAX.z);
        Vec3::new(x, y, z)
    }

    /// Uniform direction on the unit sphere.
    pub fn direction(&mut self) -> Vec3 {
        let z = self.range(-1.0, 1.0);
        let phi = self.range(0.0, std::f32::consts::TAU);
        let r = (1.0 - z * z).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), z, r * phi.sin())
    }
}

/// The standard scene: boxes, their per-frame steps, and the frame's queries.
///
/// ```
/// use bevy_rtree::scene::TownScene;
///
/// let mut town = TownScene::new(1_000, 42);
/// let before = town.boxes().to_vec();
/// let moved = town.advance_frame().to_vec();
/// assert_eq!(moved.len(), 100); // 10 % move every frame
/// assert!(moved.iter().all(|&i| town.boxes()[i as usize] != before[i as usize]));
/// ```
#[derive(Clone, Debug)]
pub struct TownScene {
    centres: Vec<Vec3>,
    half_extents: Vec<Vec3>,
    steps: Vec<Vec3>,
    boxes: Vec<Aabb>,
    order: Vec<u32>,
    moved: usize,
    frame: u64,
    rng: SceneRng,
}

impl TownScene {
    /// The entity count of the standard scene.
    pub const STANDARD_COUNT: usize = 100_000;
    /// Entities `0..10_000` are the join's "enemies".
    pub const ENEMIES: std::ops::Range<usize> = 0..10_000;
    /// Entities `10_000..15_000` are the join's "barrels".
    pub const BARRELS: std::ops::Range<usize> = 10_000..15_000;
    /// The cross join's distance, in metres.
    pub const JOIN_DISTANCE: f32 = 5.0;

    /// A scene of `count` entities from `seed` (the standard scene is
    /// `TownScene::new(TownScene::STANDARD_COUNT, seed)`).
    pub fn new(count: usize, seed: u64) -> Self {
        let mut rng = SceneRng::new(seed);
        let clusters: Vec<(f32, f32)> = (0..200)
            .map(|_| (rng.range(0.0, WORLD_MAX.x), rng.range(0.0, WORLD_MAX.z)))
            .collect();
        let mut centres = Vec::with_capacity(count);
        let mut half_extents = Vec::with_capacity(count);
        let mut steps = Vec::with_capacity(count);
        for _ in 0..count {
            let (x, z) = if rng.unit() < 0.7 {
                let (cx, cz) = clusters[rng.below(clusters.len())];
                (
                    (cx + 30.0 * rng.normal()).clamp(0.0, WORLD_MAX.x),
                    (cz + 30.0 * rng.normal()).clamp(0.0, WORLD_MAX.z),
                )
            } else {
                (rng.range(0.0, WORLD_MAX.x), rng.range(0.0, WORLD_MAX.z))
            };
            centres.push(Vec3::new(x, rng.range(0.0, WORLD_MAX.y), z));
            let class = rng.unit();
            let (lo, hi) = if class < 0.7 {
                (0.25, 1.0)
            } else if class < 0.95 {
                (1.0, 5.0)
            } else {
                (5.0, 25.0)
            };
            half_extents.push(Vec3::new(
                rng.range(lo, hi),
                rng.range(lo, hi),
                rng.range(lo, hi),
            ));
            steps.push(Vec3::new(
                rng.range(-0.1, 0.1),
                rng.range(-0.1, 0.1),
                rng.range(-0.1, 0.1),
            ));
        }
        let boxes = centres
            .iter()
            .zip(&half_extents)
            .map(|(&c, &h)| Aabb {
                min: c - h,
                max: c + h,
            })
            .collect();
        TownScene {
            centres,
            half_extents,
            steps,
            boxes,
            order: (0..count as u32).collect(),
            moved: 0,
            frame: 0,
            rng,
        }
    }

    /// Number of entities.
    pub fn len(&self) -> usize {
        self.boxes.len()
    }

    /// Whether the scene has no entities.
    pub fn is_empty(&self) -> bool {
        self.boxes.is_empty()
    }

    /// Every entity's current box, indexed by entity.
    pub fn boxes(&self) -> &[Aabb] {
        &self.boxes
    }

    /// A tree bulk-loaded from the current boxes, keyed by entity index, and
    /// the handle of each entity (`ids[i]` for entity `i`).
    pub fn bulk_loaded_tree(&self) -> (RTree<u32>, Vec<ProxyId>) {
        let mut tree = RTree::new();
        let ids = tree
            .insert_bulk(self.boxes.iter().enumerate().map(|(i, b)| (i as u32, *b)))
            .expect("scene boxes are valid");
        (tree, ids)
    }

    /// Frames advanced so far.
    pub fn frame(&self) -> u64 {
        self.frame
    }

    /// Moves a fresh random 10 % of the entities by their step (bouncing off
    /// the world's edges) and returns their indices.
    pub fn advance_frame(&mut self) -> &[u32] {
        let n = self.order.len();
        let k = n / 10;
        // Partial Fisher-Yates: the first k of `order` become a fresh sample.
        for i in 0..k {
            let j = i + self.rng.below(n - i);
            self.order.swap(i, j);
        }
        for &index in &self.order[..k] {
            let i = index as usize;
            let mut next = self.centres[i] + self.steps[i];
            for axis in 0..3 {
                if next[axis] < 0.0 || next[axis] > WORLD_MAX[axis] {
                    self.steps[i][axis] = -self.steps[i][axis];
                    next[axis] = self.centres[i][axis] + self.steps[i][axis];
                }
            }
            self.centres[i] = next;
            let h = self.half_extents[i];
            self.boxes[i] = Aabb {
                min: next - h,
                max: next + h,
            };
        }
        self.moved = k;
        self.frame += 1;
        &self.order[..k]
    }

    /// The entities moved by the last [`TownScene::advance_frame`].
    pub fn moved(&self) -> &[u32] {
        &self.order[..self.moved]
    }

    /// The eye of the scene's camera.
    pub fn eye() -> Vec3 {
        Vec3::new(1000.0, 50.0, 1000.0)
    }

    /// The camera orientation at the current frame: yaw turns once per 60
    /// frames, pitch -10 degrees.
    pub fn camera_rotation(&self) -> Quat {
        let yaw = std::f32::consts::TAU * (self.frame % 60) as f32 / 60.0;
        Quat::from_euler(EulerRot::YXZ, yaw, (-10.0f32).to_radians(), 0.0)
    }

    /// The camera frustum at the current frame: fov 60 degrees, 16:9, near
    /// 0.1 m, far 500 m.
    pub fn frustum(&self) -> Frustum {
        Frustum::perspective(
            Self::eye(),
            self.camera_rotation(),
            60f32.to_radians(),
            16.0 / 9.0,
            0.1,
            500.0,
        )
        .expect("the scene's camera is valid")
    }

    /// `count` incoherent rays: origin uniform in the world, direction uniform
    /// on the sphere, length 200 m.
    pub fn incoherent_rays(&mut self, count: usize) -> Vec<Ray> {
        (0..count)
            .map(|_| Ray {
                origin: self.rng.point_in_world(),
                dir: self.rng.direction(),
                max_t: 200.0,
            })
            .collect()
    }

    /// The lowest point above [`TownScene::eye`], in steps of 0.5 m, that no
    /// entity's box contains now: an eye whose rays all have to walk the
    /// tree (from the standard eye, inside boxes, every first hit is at
    /// `t = 0`).
    pub fn clear_eye(&self) -> Vec3 {
        (0..)
            .map(|step| Self::eye() + Vec3::Y * (0.5 * step as f32))
            .find(|&eye| !self.boxes.iter().any(|b| b.contains_point(eye)))
            .expect("finitely many finite boxes leave a point above them clear")
    }

    /// [`TownScene::coherent_rays`] from `eye` instead of the standard eye.
    pub fn coherent_rays_from(&self, eye: Vec3) -> Vec<Ray> {
        let mut rays = self.coherent_rays();
        for ray in &mut rays {
            ray.origin = eye;
        }
        rays
    }

    /// 1,000 coherent rays from the eye through a 40 x 25 pixel grid of the
    /// current camera, length 500 m.
    pub fn coherent_rays(&self) -> Vec<Ray> {
        let rotation = self.camera_rotation();
        let tan_y = (30f32).to_radians().tan();
        let tan_x = tan_y * 16.0 / 9.0;
        let mut rays = Vec::with_capacity(1000);
        for row in 0..25 {
            for col in 0..40 {
                let sx = ((col as f32 + 0.5) / 40.0 * 2.0 - 1.0) * tan_x;
                let sy = ((row as f32 + 0.5) / 25.0 * 2.0 - 1.0) * tan_y;
                let dir = rotation * crate::geometry::unit_or_nan(Vec3::new(sx, sy, -1.0));
                rays.push(Ray {
                    origin: Self::eye(),
                    dir,
                    max_t: 500.0,
                });
            }
        }
        rays
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_clear_eye_is_above_the_eye_and_inside_no_box() {
        let scene = TownScene::new(100_000, 3);
        let eye = scene.clear_eye();
        assert_eq!((eye.x, eye.z), (TownScene::eye().x, TownScene::eye().z));
        assert!(eye.y >= TownScene::eye().y);
        assert!(scene.boxes().iter().all(|b| !b.contains_point(eye)));
        let rays = scene.coherent_rays_from(eye);
        assert_eq!(rays.len(), scene.coherent_rays().len());
        assert!(rays.iter().all(|r| r.origin == eye));
    }
}
