//! View frustums as eye-relative half-spaces ([contract S7](crate::contract)).

#[cfg(feature = "reflect")]
use bevy_reflect::{ReflectDeserialize, ReflectSerialize};
use glam::{Quat, Vec3};

use super::SpatialError;

/// One half-space of a frustum, relative to the frustum's eye.
///
/// A point `p` is inside when `dot(normal, p - eye) + offset > 0`. The pattern
/// `normal = 0, offset = +inf` is *inactive*: it never culls (an infinite far
/// plane). Any other plane needs a finite, non-zero normal and a finite offset.
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Debug, PartialEq, Clone))]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HalfSpace {
    /// Points towards the inside. Need not be unit length.
    pub normal: Vec3,
    /// Offset relative to the eye: `dot(normal, p - eye) + offset`.
    pub offset: f32,
}

impl HalfSpace {
    /// The plane that never culls.
    pub const INACTIVE: HalfSpace = HalfSpace {
        normal: Vec3::ZERO,
        offset: f32::INFINITY,
    };

    /// Whether this is the inactive pattern.
    #[inline]
    pub fn is_inactive(&self) -> bool {
        self.normal == Vec3::ZERO && self.offset == f32::INFINITY
    }

    fn is_valid(&self) -> bool {
        self.is_inactive()
            || (self.normal.is_finite() && self.normal != Vec3::ZERO && self.offset.is_finite())
    }

    /// The same half-space with its normal and offset multiplied by the
    /// power of two that brings the normal's largest component into
    /// `(0.5, 1]` (the offset given in `f64`, so that re-basing it on an eye
    /// cannot overflow first).
    ///
    /// Scaling by a power of two is exact, so every plane value the culling
    /// test computes is exactly scaled too and no answer changes, except
    /// where a normal component or the offset is so much smaller than the
    /// largest component that it scales into `f32`'s subnormals: there an
    /// offset is rounded upward (the plane keeps a little more) and a
    /// normal component to nearest. With
    /// normals of that size the products `n·(p - eye)` of any point of the
    /// world can neither overflow (a normal of 1e30) nor lose their
    /// precision in subnormals (a normal of 1e-40). An offset so large that
    /// it overflows in `f32` belongs to a plane that no point within
    /// [`MAX_COORD`](crate::MAX_COORD) of the eye can reach: it never culls
    /// (inactive) or culls everything (`-f32::MAX`). A normal that is zero,
    /// or a normal or offset that is not finite, is left for validation to
    /// refuse.
    fn normalized(normal: Vec3, offset: f64) -> HalfSpace {
        let largest = normal.abs().max_element();
        if !(largest.is_finite() && largest > 0.0 && offset.is_finite()) {
            return HalfSpace {
                normal,
                offset: offset as f32,
            };
        }
        // 2^-e with e the exponent that puts `largest` in (0.5, 1].
        let exponent = (largest as f64).log2().ceil() as i32;
        let mut scale = 2f64.powi(-exponent);
        if largest as f64 * scale <= 0.5 {
            scale *= 2.0;
        }
        let scaled = offset * scale;
        let offset = if scaled > f32::MAX as f64 {
            return HalfSpace::INACTIVE;
        } else if scaled < -(f32::MAX as f64) {
            -f32::MAX
        } else {
            // Upward where `f32` cannot hold it (an offset re-based on an
            // eye in `f64`, or one scaled into the subnormals, as an offset
            // of 1e-30 beside a normal of 1e30): the plane then keeps a
            // little more, never less, so a conservative cull stays so.
            let rounded = scaled as f32;
            if (rounded as f64) < scaled {
                rounded.next_up()
            } else {
                rounded
            }
        };
        HalfSpace {
            normal: (normal.as_dvec3() * scale).as_vec3(),
            offset,
        }
    }
}

/// The sum of `terms` rounded to an `f64` no smaller than the exact sum
/// (the sum itself where every addition is exact), so that an offset
/// re-based on an eye never moves its plane inward: the rounding left over
/// from each addition is kept (Knuth's two-sum), and unless what is left
/// over in the end is surely below zero, the result goes one step up.
fn sum_at_least(terms: [f64; 4]) -> f64 {
    let two_sum = |a: f64, b: f64| {
        let sum = a + b;
        let b_part = sum - a;
        let a_part = sum - b_part;
        (sum, (a - a_part) + (b - b_part))
    };
    let (mut sum, mut left, mut left_mass) = (terms[0], 0.0, 0.0);
    for &term in &terms[1..] {
        let (next, rounding) = two_sum(sum, term);
        sum = next;
        left += rounding;
        left_mass += rounding.abs();
    }
    if left_mass == 0.0 {
        return sum;
    }
    let (sum, rounding) = two_sum(sum, left);
    // Adding up the leftovers may itself round, by far less than this.
    let doubt = 4.0 * f64::EPSILON * left_mass;
    if rounding < -doubt {
        sum
    } else {
        sum.next_up()
    }
}

/// A convex view volume: up to six half-spaces evaluated relative to an eye.
///
/// Planes are stored relative to the eye so that the test keeps its precision
/// near the camera even when the camera is a million metres from the origin.
///
/// ```
/// use bevy_rtree::{Aabb, Frustum};
/// use bevy_rtree::glam::{Quat, Vec3};
///
/// // Looking down -z from the origin, like a default Bevy camera.
/// let frustum = Frustum::perspective(Vec3::ZERO, Quat::IDENTITY, 60f32.to_radians(), 16.0 / 9.0, 0.1, 100.0)?;
/// let ahead = Aabb::new(Vec3::new(-1.0, -1.0, -11.0), Vec3::new(1.0, 1.0, -9.0))?;
/// let behind = Aabb::new(Vec3::new(-1.0, -1.0, 9.0), Vec3::new(1.0, 1.0, 11.0))?;
/// assert!(frustum.intersects_conservative(&ahead));
/// assert!(!frustum.intersects_conservative(&behind));
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
// Opaque: its planes are checked and scaled on construction, which an
// inspector editing fields one by one would bypass. Scenes save and load it
// through serde (`frustum_serde.rs`), loading through the same check.
#[cfg_attr(
    feature = "reflect",
    reflect(opaque, Debug, PartialEq, Clone, Serialize, Deserialize)
)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frustum {
    eye: Vec3,
    planes: [HalfSpace; 6],
}

impl Frustum {
    /// A checked frustum from an eye and six eye-relative half-spaces (use
    /// [`HalfSpace::INACTIVE`] for planes you do not need).
    ///
    /// The eye must be a valid point of the world (finite, every coordinate
    /// within [`MAX_COORD`](crate::MAX_COORD)). Each plane is stored scaled
    /// by a power of two so that its normal's largest component lies in
    /// `(0.5, 1]`: the same half-space, whose test can neither overflow nor
    /// lose precision in subnormals for any box of the world (unit normals,
    /// as [`Frustum::perspective`] makes, are kept as they are).
    ///
    /// ```
    /// use bevy_rtree::{Frustum, HalfSpace};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let huge = HalfSpace { normal: Vec3::new(0.0, 0.0, -4e30), offset: 8e30 };
    /// let i = HalfSpace::INACTIVE;
    /// let frustum = Frustum::new(Vec3::ZERO, [huge, i, i, i, i, i])?;
    /// let stored = frustum.planes()[0];
    /// assert!(stored.normal.z > -1.0 && stored.normal.z <= -0.5);
    /// assert_eq!(stored.offset / -stored.normal.z, 2.0); // still z < 2
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn new(eye: Vec3, planes: [HalfSpace; 6]) -> Result<Frustum, SpatialError> {
        let planes = planes.map(|h| {
            if h.is_inactive() {
                h
            } else {
                HalfSpace::normalized(h.normal, h.offset as f64)
            }
        });
        Frustum::checked(eye, planes)
    }

    /// Checks the eye and the (already normalized) planes.
    fn checked(eye: Vec3, planes: [HalfSpace; 6]) -> Result<Frustum, SpatialError> {
        let eye_ok = eye.is_finite() && eye.abs().max_element() <= crate::MAX_COORD;
        if !eye_ok || !planes.iter().all(HalfSpace::is_valid) {
            return Err(SpatialError::InvalidFrustum);
        }
        Ok(Frustum { eye, planes })
    }

    /// A checked frustum from world-space planes `dot(n, p) + d > 0`, re-based
    /// on `eye` (the offsets are converted in `f64`, and rounded upward where
    /// `f32` cannot hold the result: the stored offset is never below the
    /// re-based one).
    pub fn from_world_planes(eye: Vec3, planes: [(Vec3, f32); 6]) -> Result<Frustum, SpatialError> {
        let rebased = planes.map(|(normal, d)| {
            if normal == Vec3::ZERO && d == f32::INFINITY {
                return HalfSpace::INACTIVE;
            }
            let (n, e) = (normal.as_dvec3(), eye.as_dvec3());
            // Each product of two `f32` is exact in `f64`; only the sum rounds.
            let offset = sum_at_least([d as f64, n.x * e.x, n.y * e.y, n.z * e.z]);
            HalfSpace::normalized(normal, offset)
        });
        Frustum::checked(eye, rebased)
    }

    /// A symmetric perspective frustum: camera at `eye`, oriented by
    /// `rotation` (looking down its local -z, up along local +y, as in Bevy),
    /// vertical field of view `fov_y` in radians, `aspect` = width / height,
    /// `near` > 0 and `far` > `near` in metres (`far = inf` makes the far plane
    /// inactive).
    ///
    /// `rotation` is normalized first, so a quaternion that drifted from unit
    /// length (after many composed rotations, say) orients the camera as its
    /// unit quaternion does; a zero or non-finite one is an
    /// [`SpatialError::InvalidFrustum`].
    ///
    /// The side planes are built in `f32`: a field of view under about
    /// 1e-6 radians is narrower than their rounding, and may cull the very
    /// centre of the view; an opening wide enough that `tan(fov_y / 2) *
    /// aspect` overflows (about 1e19) is refused as
    /// [`SpatialError::InvalidFrustum`].
    ///
    /// ```
    /// use bevy_rtree::{Aabb, Frustum};
    /// use bevy_rtree::glam::{Quat, Vec3};
    ///
    /// let turned = Quat::from_rotation_y(0.5);
    /// let view = Frustum::perspective(Vec3::ZERO, turned, 1.0, 1.5, 0.1, 100.0)?;
    /// let drifted = Quat::from_vec4(turned.to_array().map(|c| c * 1.1).into());
    /// let same = Frustum::perspective(Vec3::ZERO, drifted, 1.0, 1.5, 0.1, 100.0)?;
    /// // The near plane stays 0.1 m from the eye: a box 0.09 m ahead is culled.
    /// let ahead = turned * Vec3::new(0.0, 0.0, -0.09);
    /// let close = Aabb::new(ahead - 0.001, ahead + 0.001)?;
    /// assert!(!view.intersects_conservative(&close));
    /// assert!(!same.intersects_conservative(&close));
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn perspective(
        eye: Vec3,
        rotation: Quat,
        fov_y: f32,
        aspect: f32,
        near: f32,
        far: f32,
    ) -> Result<Frustum, SpatialError> {
        let fov_ok = fov_y > 0.0 && fov_y < std::f32::consts::PI;
        if !(fov_ok && aspect > 0.0 && aspect.is_finite() && near > 0.0 && far > near) {
            return Err(SpatialError::InvalidFrustum);
        }
        // A quaternion of length s rotates and scales by s²: unnormalized,
        // it would move the near and far planes to near / s² and far / s².
        // Scaled by its largest component first, so that the squared length
        // of a tiny or huge (but finite, nonzero) quaternion neither
        // underflows nor overflows `f32`.
        let raw = glam::Vec4::from(rotation);
        let largest = raw.abs().max_element();
        // (`max_element` passes over a NaN: the components are checked.)
        if !(raw.is_finite() && largest > 0.0) {
            return Err(SpatialError::InvalidFrustum);
        }
        let scaled = raw / largest;
        let rotation = Quat::from_vec4(scaled * scaled.length_recip());
        let forward = rotation * Vec3::NEG_Z;
        let up = rotation * Vec3::Y;
        let right = rotation * Vec3::X;
        let tan_y = (fov_y * 0.5).tan();
        let tan_x = tan_y * aspect;
        // Side planes pass through the eye, so their eye-relative offset is 0.
        // Each inward normal is the forward axis tilted against the side axis.
        let side = |axis: Vec3, tan: f32| HalfSpace {
            normal: super::unit_or_nan(forward * tan + axis),
            offset: 0.0,
        };
        let far_plane = if far.is_finite() {
            HalfSpace {
                normal: -forward,
                offset: far,
            }
        } else {
            HalfSpace::INACTIVE
        };
        Frustum::new(
            eye,
            [
                side(right, tan_x),
                side(-right, tan_x),
                side(up, tan_y),
                side(-up, tan_y),
                HalfSpace {
                    normal: forward,
                    offset: -near,
                },
                far_plane,
            ],
        )
    }

    /// The eye the planes are relative to.
    pub fn eye(&self) -> Vec3 {
        self.eye
    }

    /// The six eye-relative half-spaces, as stored (see [`Frustum::new`]).
    pub fn planes(&self) -> &[HalfSpace; 6] {
        &self.planes
    }

    /// The conservative test ([contract S7](crate::contract), Bevy's convention): visible iff for
    /// every plane `dot(n, p - eye) + offset > 0`, with `p` the box corner
    /// furthest along `n`. A box touching a plane from outside is culled.
    #[inline]
    pub fn intersects_conservative(&self, aabb: &Aabb) -> bool {
        super::predicates::frustum_conservative(self, aabb)
    }
}

use super::Aabb;
