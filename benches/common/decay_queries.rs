//! The decay bench's query families: each run on a set of trees (all,
//! enemies, barrels), timed, and its whole answer kept in a comparable
//! form, so that a maintained tree, a fresh load and the brute-force
//! oracle can be held to the same answers.

use std::time::Instant;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::{SceneRng, TownScene};
use bevy_rtree::{Aabb, CullMode, JoinMode, QueryWorkspace, RTree, RayMode, RayResults};
use glam::Vec3;

pub const FAMILIES: [&str; 6] = [
    "cull",
    "1,000 incoherent rays",
    "1,000 coherent rays",
    "cross join",
    "self join",
    "1,000 box queries",
];

/// The result lists the families write into, kept from call to call, so
/// that no timed call grows fresh ones: growing them cost both trees the
/// same time and pulled their ratio toward 1.
#[derive(Default)]
pub struct Scratch {
    keys: Vec<u32>,
    lists: Vec<Vec<u32>>,
    ends: Vec<usize>,
    pairs: Vec<(u32, u32)>,
    rays: RayResults<u32>,
}

/// The query families' inputs.
pub struct Queries {
    frustum: bevy_rtree::Frustum,
    incoherent: Vec<bevy_rtree::Ray>,
    coherent: Vec<bevy_rtree::Ray>,
    boxes: Vec<Aabb>,
}

/// A whole answer, order made canonical: sorted keys for a cull, one
/// `(key, t)` or none per ray, sorted pairs, each box query's sorted keys
/// after a separator.
pub type Answer = Vec<u64>;

const NO_HIT: u64 = u64::MAX;
const NEXT_QUERY: u64 = u64::MAX - 1;

fn hit(key: u32, t: f32) -> u64 {
    (u64::from(key) << 32) | u64::from(t.to_bits())
}

fn pair((a, b): (u32, u32)) -> u64 {
    (u64::from(a) << 32) | u64::from(b)
}

fn sorted_keys(keys: &[u32], answer: &mut Answer) {
    let start = answer.len();
    answer.extend(keys.iter().map(|&k| u64::from(k)));
    answer[start..].sort_unstable();
}

impl Queries {
    pub fn new(scene: &mut TownScene, seed: u64) -> Queries {
        let mut rng = SceneRng::new(seed);
        Queries {
            frustum: scene.frustum(),
            incoherent: scene.incoherent_rays(1_000),
            coherent: scene.coherent_rays_from(scene.clear_eye()),
            boxes: (0..1_000)
                .map(|_| {
                    let c = rng.point_in_world();
                    Aabb {
                        min: c - Vec3::splat(5.0),
                        max: c + Vec3::splat(5.0),
                    }
                })
                .collect(),
        }
    }

    fn rays(&self, f: usize) -> &[bevy_rtree::Ray] {
        if f == 1 {
            &self.incoherent
        } else {
            &self.coherent
        }
    }

    /// Runs family `f` on `trees`: the time in ms (the query alone), and
    /// its answer.
    pub fn run(
        &self,
        f: usize,
        trees: [&RTree<u32>; 3],
        ws: &mut QueryWorkspace,
        scratch: &mut Scratch,
    ) -> (f64, Answer) {
        let Scratch {
            keys,
            lists,
            ends,
            pairs,
            rays,
        } = scratch;
        keys.clear();
        lists.iter_mut().for_each(Vec::clear);
        ends.clear();
        pairs.clear();
        let start = Instant::now();
        match f {
            0 => trees[0].visible_into(
                std::slice::from_ref(&self.frustum),
                CullMode::Conservative,
                ws,
                lists,
            ),
            1 | 2 => trees[0].cast_rays(self.rays(f), RayMode::First, ws, rays),
            3 => trees[1]
                .cross_join_into(
                    trees[2],
                    TownScene::JOIN_DISTANCE,
                    JoinMode::Euclidean,
                    ws,
                    pairs,
                )
                .unwrap(),
            4 => trees[0]
                .self_join_into(0.0, JoinMode::Euclidean, ws, pairs)
                .unwrap(),
            _ => {
                for b in &self.boxes {
                    trees[0].overlapping_into(b, ws, keys);
                    ends.push(keys.len());
                }
            }
        }
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let mut answer = Answer::new();
        match f {
            0 => sorted_keys(&lists[0], &mut answer),
            1 | 2 => answer.extend(
                (0..self.rays(f).len()).map(|i| match rays.first(i).unwrap() {
                    Some(h) => hit(h.key, h.t),
                    None => NO_HIT,
                }),
            ),
            3 | 4 => {
                answer.extend(pairs.iter().copied().map(pair));
                answer.sort_unstable();
            }
            _ => {
                let mut from = 0;
                for &end in ends.iter() {
                    sorted_keys(&keys[from..end], &mut answer);
                    answer.push(NEXT_QUERY);
                    from = end;
                }
            }
        }
        (ms, answer)
    }

    /// Every family's answer on `trees`, held to the brute-force oracle's
    /// over the same entries (same predicates, no tree).
    pub fn check_against_the_oracle(&self, trees: [&RTree<u32>; 3]) {
        let oracles = trees.map(|tree| {
            let mut oracle = BruteForce::default();
            for (_, key, aabb) in tree.iter() {
                oracle.insert(key, aabb);
            }
            oracle
        });
        let mut ws = QueryWorkspace::default();
        let mut scratch = Scratch::default();
        for (f, family) in FAMILIES.iter().enumerate() {
            let mut expected = Answer::new();
            match f {
                0 => sorted_keys(
                    &oracles[0].visible(&self.frustum, CullMode::Conservative),
                    &mut expected,
                ),
                1 | 2 => expected.extend(self.rays(f).iter().map(|ray| {
                    match oracles[0].ray_first(ray).unwrap() {
                        Some(h) => hit(h.key, h.t),
                        None => NO_HIT,
                    }
                })),
                3 => {
                    let pairs = oracles[1]
                        .cross_join(&oracles[2], TownScene::JOIN_DISTANCE, JoinMode::Euclidean)
                        .unwrap();
                    expected.extend(pairs.into_iter().map(pair));
                }
                4 => {
                    let pairs = oracles[0].self_join(0.0, JoinMode::Euclidean).unwrap();
                    expected.extend(pairs.into_iter().map(pair));
                }
                _ => {
                    for b in &self.boxes {
                        sorted_keys(&oracles[0].overlapping(b), &mut expected);
                        expected.push(NEXT_QUERY);
                    }
                }
            }
            let (_, answer) = self.run(f, trees, &mut ws, &mut scratch);
            assert!(!expected.is_empty(), "{family}: the oracle found nothing");
            assert!(
                answer == expected,
                "{family}: the tree and the oracle differ"
            );
        }
    }
}

/// The nodes every family visits on each set of trees.
pub fn nodes_visited(queries: &Queries, sets: [[&RTree<u32>; 3]; 2]) -> [u64; 2] {
    let mut ws = QueryWorkspace::default();
    let mut scratch = Scratch::default();
    sets.map(|set| {
        (0..FAMILIES.len())
            .map(|f| {
                ws.take_stats();
                queries.run(f, set, &mut ws, &mut scratch);
                ws.stats().nodes_visited
            })
            .sum()
    })
}
