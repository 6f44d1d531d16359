//! The brute-force contender: a structure-of-arrays box list, tested 16
//! boxes at a time into a bit mask (a loop the compiler vectorises).

use bevy_rtree::Aabb;

pub(crate) struct SoaBoxes {
    min: [Vec<f32>; 3],
    max: [Vec<f32>; 3],
}

impl SoaBoxes {
    const LANES: usize = 16;

    pub(crate) fn new(boxes: &[Aabb]) -> Self {
        let axis = |f: &dyn Fn(&Aabb) -> f32| boxes.iter().map(f).collect::<Vec<f32>>();
        SoaBoxes {
            min: [axis(&|b| b.min.x), axis(&|b| b.min.y), axis(&|b| b.min.z)],
            max: [axis(&|b| b.max.x), axis(&|b| b.max.y), axis(&|b| b.max.z)],
        }
    }

    /// Appends the indices of all boxes overlapping `q` (closed boxes).
    pub(crate) fn overlapping_into(&self, q: &Aabb, out: &mut Vec<u32>) {
        let n = self.min[0].len();
        let (qmin, qmax) = (q.min.to_array(), q.max.to_array());
        let full = n / Self::LANES * Self::LANES;
        for base in (0..full).step_by(Self::LANES) {
            let end = base + Self::LANES;
            let (x0, y0, z0) = (
                &self.min[0][base..end],
                &self.min[1][base..end],
                &self.min[2][base..end],
            );
            let (x1, y1, z1) = (
                &self.max[0][base..end],
                &self.max[1][base..end],
                &self.max[2][base..end],
            );
            let mut mask = 0u32;
            for j in 0..Self::LANES {
                let hit = (x0[j] <= qmax[0])
                    & (x1[j] >= qmin[0])
                    & (y0[j] <= qmax[1])
                    & (y1[j] >= qmin[1])
                    & (z0[j] <= qmax[2])
                    & (z1[j] >= qmin[2]);
                mask |= (hit as u32) << j;
            }
            while mask != 0 {
                let j = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                out.push((base + j) as u32);
            }
        }
        for i in full..n {
            let hit = (0..3).all(|a| self.min[a][i] <= qmax[a] && self.max[a][i] >= qmin[a]);
            if hit {
                out.push(i as u32);
            }
        }
    }
}
