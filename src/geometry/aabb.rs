//! Axis-aligned boxes ([contract S0](crate::contract), S1).

use glam::{Affine3A, Vec3, Vec3A};

use super::SpatialError;

/// The largest coordinate magnitude a valid box may have, in metres.
///
/// Far beyond any game world, yet small enough that sums and products used by
/// the tree's heuristics (computed in `f64`) can never overflow.
pub const MAX_COORD: f32 = 1e15;

/// A closed, axis-aligned box in world space, stored as `min` / `max` corners.
///
/// Faces, edges and corners belong to the box. A box is *valid* when all six
/// numbers are finite, `min <= max` on every axis and every magnitude is at
/// most [`MAX_COORD`]. Zero extent (points, flat boxes) is valid; `-0.0` and
/// `+0.0` are the same number.
///
/// The fields are public because an `Aabb` is a plain value; every mutation
/// of the index checks validity and refuses an invalid box with
/// [`SpatialError::InvalidBox`], and a box query with an invalid box matches
/// nothing.
///
/// ```
/// use bevy_rtree::Aabb;
/// use bevy_rtree::glam::Vec3;
///
/// let unit = Aabb::new(Vec3::ZERO, Vec3::ONE)?;
/// let touching = Aabb::new(Vec3::new(1.0, 0.0, 0.0), Vec3::new(2.0, 1.0, 1.0))?;
/// assert!(unit.intersects(&touching)); // closed boxes: a shared face counts
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Debug, PartialEq, Clone))]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// The corner with the smallest coordinates.
    pub min: Vec3,
    /// The corner with the largest coordinates.
    pub max: Vec3,
}

impl Aabb {
    /// The inverted box (`min = +inf`, `max = -inf`): the identity of
    /// [`Aabb::union`] and a box that intersects nothing. Not valid as an entry.
    pub const INVERTED: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// What a world box that cannot be computed is (NaN corners): not valid,
    /// so the plugin leaves the entity out and reports it, whereas it reads
    /// [`Aabb::INVERTED`], the default `SpatialBounds`, as "no box yet".
    #[cfg(feature = "bevy")]
    pub(crate) const UNUSABLE: Aabb = Aabb {
        min: Vec3::NAN,
        max: Vec3::NAN,
    };

    /// The box of all space (`min = -inf`, `max = +inf`): contains every
    /// box. Not valid as an entry.
    pub(crate) const EVERYWHERE: Aabb = Aabb {
        min: Vec3::splat(f32::NEG_INFINITY),
        max: Vec3::splat(f32::INFINITY),
    };

    /// A checked box from its corners.
    pub fn new(min: Vec3, max: Vec3) -> Result<Aabb, SpatialError> {
        let aabb = Aabb { min, max };
        aabb.validate()?;
        Ok(aabb)
    }

    /// A checked box from a centre and non-negative half extents.
    ///
    /// The corners are computed once, in `f32`; the box is stored as min/max
    /// from then on ([contract S0](crate::contract) explains why never centre/half-extents).
    pub fn from_center_half_extents(center: Vec3, half: Vec3) -> Result<Aabb, SpatialError> {
        if !(half.cmpge(Vec3::ZERO).all()) {
            return Err(SpatialError::InvalidBox);
        }
        Aabb::new(center - half, center + half)
    }

    /// The zero-extent box at `point`.
    pub fn from_point(point: Vec3) -> Result<Aabb, SpatialError> {
        Aabb::new(point, point)
    }

    /// Whether the box is valid as an entry or query (see the type docs).
    #[inline]
    pub fn is_valid(&self) -> bool {
        // NaN fails every comparison and an infinity exceeds the bound, so
        // these three tests also reject every non-finite coordinate. In
        // `Vec3A`, without a branch: a batch of moves checks every box.
        let bound = Vec3A::splat(MAX_COORD);
        let (min, max) = (Vec3A::from(self.min), Vec3A::from(self.max));
        (min.cmple(max) & min.abs().cmple(bound) & max.abs().cmple(bound)).all()
    }

    /// `Ok(())` when [`Aabb::is_valid`], else [`SpatialError::InvalidBox`].
    #[inline]
    pub fn validate(&self) -> Result<(), SpatialError> {
        if self.is_valid() {
            Ok(())
        } else {
            Err(SpatialError::InvalidBox)
        }
    }

    /// Whether the two closed boxes share at least one point.
    #[inline]
    pub fn intersects(&self, other: &Aabb) -> bool {
        super::predicates::boxes_overlap(self, other)
    }

    /// Whether `other` lies entirely inside `self` (faces may coincide).
    #[inline]
    pub fn contains(&self, other: &Aabb) -> bool {
        self.min.cmple(other.min).all() && other.max.cmple(self.max).all()
    }

    /// Whether the closed box contains `point`.
    #[inline]
    pub fn contains_point(&self, point: Vec3) -> bool {
        self.min.cmple(point).all() && point.cmple(self.max).all()
    }

    /// The smallest box containing both.
    #[inline]
    pub fn union(&self, other: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
        }
    }

    /// The box grown by `amount` (per axis, non-negative) on every side.
    #[inline]
    pub fn grown(&self, amount: Vec3) -> Aabb {
        Aabb {
            min: self.min - amount,
            max: self.max + amount,
        }
    }

    /// Extent per axis (`max - min`).
    #[inline]
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }

    /// The centre, computed in `f64` so that it cannot overflow for valid boxes.
    #[inline]
    pub fn center_f64(&self) -> [f64; 3] {
        let c = |i: usize| (self.min[i] as f64 + self.max[i] as f64) * 0.5;
        [c(0), c(1), c(2)]
    }

    /// Half the surface area, in `f64` (cannot overflow for valid boxes).
    /// Zero-extent boxes have zero area; the tree's heuristics pair it with
    /// [`Aabb::margin`] so flat boxes still order sensibly.
    #[inline]
    pub fn half_area(&self) -> f64 {
        let e = self.extent().as_dvec3();
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    /// The sum of extents (the R*-tree "margin"), in `f64`.
    #[inline]
    pub fn margin(&self) -> f64 {
        let e = self.extent().as_dvec3();
        e.x + e.y + e.z
    }

    /// The world box of a local box under an affine transform ([contract S1](crate::contract)).
    ///
    /// centre' = M * centre, half' = |M3x3| * half, evaluated in `f64` from
    /// the `f32` inputs; unless the transform is a pure translation, min is
    /// then rounded down and max up to `f32`, past the `f64` evaluation's
    /// own error bound, so that the result contains the exact image of every
    /// corner of the local box, however far from the origin (in `f32`, the
    /// rounding of the centre alone can exceed an ulp of the result). A pure
    /// translation adds in `f32` (`min + t`, `max + t`), as every other
    /// point of the entity is moved. A result beyond [`MAX_COORD`] is an
    /// [`SpatialError::InvalidBox`].
    ///
    /// ```
    /// use bevy_rtree::Aabb;
    /// use bevy_rtree::glam::{Affine3A, Vec3};
    ///
    /// let local = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0))?;
    /// let world = local.transformed(&Affine3A::from_translation(Vec3::X * 10.0))?;
    /// assert_eq!(world.min, Vec3::new(9.0, -1.0, -1.0));
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn transformed(&self, transform: &Affine3A) -> Result<Aabb, SpatialError> {
        self.validate()?;
        let m = transform.matrix3;
        if !(m.is_finite() && transform.translation.is_finite()) {
            return Err(SpatialError::InvalidBox);
        }
        let pure_translation = m == glam::Mat3A::IDENTITY;
        if pure_translation {
            let t = Vec3::from(transform.translation);
            return Aabb::new(self.min + t, self.max + t);
        }
        let center = (self.min.as_dvec3() + self.max.as_dvec3()) * 0.5;
        let half = (self.max.as_dvec3() - self.min.as_dvec3()) * 0.5;
        outward_image(center, half, transform)
    }

    /// The world box of an oriented box given, as Bevy's `Aabb` component
    /// gives it, by a local `center` and non-negative `half_extents`: a box
    /// that contains the exact image of every corner under `transform`.
    ///
    /// Evaluated in `f32`, four lanes at a time, and widened on every side
    /// by 16 units of roundoff of the magnitudes that enter each coordinate
    /// (`|M|·|c| + |t| + |M|·h`), past the error bound of the evaluation (at
    /// most about 10 of them), so containment holds however far from the
    /// origin, at a few nanoseconds a box; [`Aabb::transformed`] is the
    /// tighter `f64` form. A negative, NaN or infinite input, a transform
    /// that is not finite or a result beyond [`MAX_COORD`] is an
    /// [`SpatialError::InvalidBox`].
    ///
    /// ```
    /// use bevy_rtree::Aabb;
    /// use bevy_rtree::glam::{Affine3A, Quat, Vec3};
    ///
    /// let turned = Affine3A::from_rotation_translation(Quat::from_rotation_y(0.3), Vec3::X * 100.0);
    /// let world = Aabb::from_oriented(Vec3::ZERO, Vec3::ONE, &turned)?;
    /// for corner in [Vec3::ONE, -Vec3::ONE, Vec3::new(1.0, -1.0, 1.0)] {
    ///     assert!(world.contains_point(turned.transform_point3(corner)));
    /// }
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    #[inline]
    pub fn from_oriented(
        center: Vec3,
        half_extents: Vec3,
        transform: &Affine3A,
    ) -> Result<Aabb, SpatialError> {
        let (c, h) = (Vec3A::from(center), Vec3A::from(half_extents));
        let m = transform.matrix3;
        let abs = glam::Mat3A::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs());
        let world_center = m * c + transform.translation;
        let world_half = abs * h;
        let scale = abs * c.abs() + transform.translation.abs() + world_half;
        // 16 u of the magnitudes, and the smallest normal float so that
        // subnormal roundings are covered too.
        let slack = scale * (16.0 * f32::EPSILON * 0.5) + f32::MIN_POSITIVE;
        let aabb = Aabb {
            min: Vec3::from(world_center - world_half - slack),
            max: Vec3::from(world_center + world_half + slack),
        };
        // A negative half extent or any NaN leaves `min > max` or a NaN,
        // and an infinity exceeds the bound: validation refuses them all.
        if !(h.cmpge(Vec3A::ZERO).all() && scale.is_finite()) {
            return Err(SpatialError::InvalidBox);
        }
        aabb.validate()?;
        Ok(aabb)
    }
}

/// S1 in `f64`: the image of the box `center ± half` under `transform`,
/// rounded outward to `f32` past the evaluation's own error bound.
fn outward_image(
    center: glam::DVec3,
    half: glam::DVec3,
    transform: &Affine3A,
) -> Result<Aabb, SpatialError> {
    // The error budget, with u = 2^-53 and `scale` below (the sum of the
    // magnitudes that enter a coordinate): the centre and half extents
    // round by at most u of themselves, each 3-term product row with the
    // translation by at most 4u of its magnitudes, the half extents' row by
    // 3u, and the final sum and the slack's own subtraction by one rounding
    // each: about 7u * scale in all. `slack` is 16u * scale.
    let matrix = glam::Mat3::from(transform.matrix3).as_dmat3();
    let abs = matrix.abs();
    let translation = Vec3::from(transform.translation).as_dvec3();
    let world_center = matrix * center + translation;
    let world_half = abs * half;
    let scale = abs * center.abs() + translation.abs() + world_half;
    let slack = scale * (8.0 * f64::EPSILON);
    let min = (world_center - world_half - slack)
        .to_array()
        .map(f32_at_most);
    let max = (world_center + world_half + slack)
        .to_array()
        .map(f32_at_least);
    Aabb::new(Vec3::from_array(min), Vec3::from_array(max))
}

/// The largest `f32` not above `x` (`x` finite).
fn f32_at_most(x: f64) -> f32 {
    let nearest = x as f32;
    if f64::from(nearest) > x {
        nearest.next_down()
    } else {
        nearest
    }
}

/// The smallest `f32` not below `x` (`x` finite).
fn f32_at_least(x: f64) -> f32 {
    let nearest = x as f32;
    if f64::from(nearest) < x {
        nearest.next_up()
    } else {
        nearest
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `is_valid` against the rule spelled out coordinate by coordinate
    /// (finite, within `MAX_COORD`, `min <= max`), over every combination
    /// of values at and around the limits, NaN and both infinities.
    #[test]
    fn validity_matches_the_rule_on_every_special_value() {
        let values = [
            0.0,
            -0.0,
            1.0,
            MAX_COORD,
            -MAX_COORD,
            MAX_COORD.next_up(),
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ];
        let rule = |min: [f32; 3], max: [f32; 3]| {
            (0..3).all(|a| {
                let ok = |v: f32| v.is_finite() && v.abs() <= MAX_COORD;
                ok(min[a]) && ok(max[a]) && min[a] <= max[a]
            })
        };
        let n = values.len();
        for code in 0..n.pow(6) {
            let pick = |slot: u32| values[code / n.pow(slot) % n];
            let (min, max) = ([pick(0), pick(1), pick(2)], [pick(3), pick(4), pick(5)]);
            let aabb = Aabb {
                min: Vec3::from(min),
                max: Vec3::from(max),
            };
            assert_eq!(aabb.is_valid(), rule(min, max), "{min:?} {max:?}");
        }
    }
}
