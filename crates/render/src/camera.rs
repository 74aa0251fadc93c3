//! Pinhole cameras: the pitch/yaw model of the course notes the renderer started from
//! (A. Delval, "Path tracing: méthodes de Monte Carlo pour la synthèse d'images", Projet de
//! Programmation Numérique, 2024, eqs. 1–12) and look-at.
//!
//! Both reduce to an eye, an orthonormal basis (forward t, right b, up v) and the size of one
//! pixel on the image plane at distance 1. A film point in continuous pixel coordinates
//! (x right, y down, (0, 0) the top-left corner) maps to the direction
//! `t + (x − W/2)·sx·b + (H/2 − y)·sy·v`, so sampling x, y uniformly over a pixel's square is
//! the box filter: the pixel value is the mean radiance over its square.
//!
//! An orthographic camera (glTF's) moves the ray's origin over the film instead, by the same
//! basis scaled to the film's size in world units, and keeps its direction.
//!
//! A near clipping distance (glTF's `znear`, Blender's clip start) starts each ray on the
//! plane that far ahead of the eye instead of at the eye, so that what lies nearer is not seen:
//! the way to look into a room from behind its wall. A far clipping distance (glTF's `zfar`,
//! Blender's clip end) ends a camera ray's first segment on the plane that far ahead: what lies
//! beyond is not seen, and the ray sees the environment there instead.

use glam::Vec3A;

use crate::util::math::Ray;

/// A pinhole camera.
#[derive(Clone, Debug)]
pub struct Camera {
    eye: Vec3A,
    forward: Vec3A,
    right: Vec3A,
    up: Vec3A,
    width: f32,
    height: f32,
    /// Parallel rays from points of the film (`right` and `up` are then world lengths).
    orthographic: bool,
    /// Depth of the near clipping plane along `forward`; 0 for none.
    near: f32,
    /// Depth of the far clipping plane along `forward`; infinite for none.
    far: f32,
}

/// The camera's trigonometry in f64, rounded once to f32. The f32 library functions are chosen
/// per CPU at load time and may round differently, and a camera basis one bit off would change
/// every pixel a worker returns; an f64 result one f64 ulp off changes the f32 only when it lies
/// within that ulp of a rounding boundary.
fn sin_cos(x: f32) -> (f32, f32) {
    let (s, c) = f64::from(x).sin_cos();
    (s as f32, c as f32)
}

/// tan(fov/2), as [`sin_cos`].
fn half_tan(fov: f32) -> f32 {
    (f64::from(fov) * 0.5).tan() as f32
}

impl Camera {
    /// The course model. `fov` is θ in radians; as in eqs. 7–9 the viewport width
    /// h_x = 2·tan(θ/2) spans the centres of the first and last pixel columns, so one pixel is
    /// h_x/(k − 1) wide (k = `width` ≥ 2), and pixels are square (eq. 8).
    pub fn pitch_yaw(eye: Vec3A, pitch: f32, yaw: f32, fov: f32, width: u32, height: u32) -> Self {
        let ((sa, ca), (sb, cb)) = (sin_cos(pitch), sin_cos(yaw));
        let t = Vec3A::new(ca * cb, sa, -ca * sb); // eq. 4
        let v = Vec3A::new(-sa * cb, ca, sa * sb); // eq. 5
        let b = Vec3A::new(sb, 0.0, cb); // eq. 6
        let q = 2.0 * half_tan(fov) / (width as f32 - 1.0); // eqs. 7, 9
        Self {
            eye,
            forward: t,
            right: b * q,
            up: v * q,
            width: width as f32,
            height: height as f32,
            orthographic: false,
            near: 0.0,
            far: f32::INFINITY,
        }
    }

    /// Look-at camera with horizontal field of view `fov` (radians) spanning the film's
    /// outer edges. Returns `None` if `up` is parallel to the view direction.
    pub fn look_at(
        eye: Vec3A,
        target: Vec3A,
        up: Vec3A,
        fov: f32,
        width: u32,
        height: u32,
    ) -> Option<Self> {
        let t = (target - eye).try_normalize()?;
        let b = t.cross(up).try_normalize()?;
        let v = b.cross(t);
        let s = 2.0 * half_tan(fov) / width as f32;
        Some(Self {
            eye,
            forward: t,
            right: b * s,
            up: v * s,
            width: width as f32,
            height: height as f32,
            orthographic: false,
            near: 0.0,
            far: f32::INFINITY,
        })
    }

    /// An orthographic camera at `eye` looking along `forward`, whose film spans `xmag` and
    /// `ymag` world units either side of its centre (glTF's half-widths): parallel rays from
    /// the film's points. Returns `None` for a degenerate basis or a non-positive size.
    pub fn orthographic(
        eye: Vec3A,
        forward: Vec3A,
        up: Vec3A,
        (xmag, ymag): (f32, f32),
        width: u32,
        height: u32,
    ) -> Option<Self> {
        let t = forward.try_normalize()?;
        let b = t.cross(up).try_normalize()?;
        let v = b.cross(t);
        let ok = |m: f32| m.is_finite() && m > 0.0;
        if !ok(xmag) || !ok(ymag) {
            return None;
        }
        Some(Self {
            eye,
            forward: t,
            right: b * (2.0 * xmag / width as f32),
            up: v * (2.0 * ymag / height as f32),
            width: width as f32,
            height: height as f32,
            orthographic: true,
            near: 0.0,
            far: f32::INFINITY,
        })
    }

    /// The camera with its near clipping plane `near` world units ahead of the eye, along the
    /// view axis; 0 (or anything not finite and positive) clips nothing.
    pub fn with_near(self, near: f32) -> Self {
        let near = if near.is_finite() && near > 0.0 {
            near
        } else {
            0.0
        };
        Self { near, ..self }
    }

    /// The camera with its far clipping plane `far` world units ahead of the eye, along the
    /// view axis; anything not finite, or not beyond the near plane, clips nothing.
    pub fn with_far(self, far: f32) -> Self {
        let far = if far.is_finite() && far > self.near {
            far
        } else {
            f32::INFINITY
        };
        Self { far, ..self }
    }

    /// Whether the camera clips what lies far away.
    pub fn clips_far(&self) -> bool {
        self.far.is_finite()
    }

    /// How far a primary ray of (normalised) direction `d` may travel from its origin before
    /// it passes the far plane; infinite without one.
    #[inline]
    pub fn far_t(&self, d: Vec3A) -> f32 {
        if !self.clips_far() {
            return f32::INFINITY;
        }
        let along = d.dot(self.forward);
        if along > 0.0 {
            (self.far - self.near) / along
        } else {
            f32::INFINITY
        }
    }

    /// Primary ray through film point (x, y).
    #[inline]
    pub fn ray(&self, x: f32, y: f32) -> Ray {
        if self.orthographic {
            let film = self.right * (x - 0.5 * self.width) + self.up * (0.5 * self.height - y);
            return Ray::new(self.eye + film + self.forward * self.near, self.forward);
        }
        let d =
            self.forward + self.right * (x - 0.5 * self.width) + self.up * (0.5 * self.height - y);
        // `d` is one unit deep along the axis (`right` and `up` are across it), so `near · d`
        // is on the clipping plane. Without clipping the origin keeps the eye's bits.
        let o = if self.near > 0.0 {
            self.eye + d * self.near
        } else {
            self.eye
        };
        Ray::new(o, d.normalize())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pitch_yaw_basis_matches_the_notes() {
        // α = β = 0: t0 = +x, v0 = +y, b0 = +z (eq. 1).
        let c = Camera::pitch_yaw(Vec3A::ZERO, 0.0, 0.0, 1.0, 5, 5);
        let centre = c.ray(2.5, 2.5);
        assert!((centre.d - Vec3A::X).length() < 1e-6);
        // Column 0's centre is at −h_x/2 along b (eq. 10): angle θ/2 off-axis.
        let left = c.ray(0.5, 2.5);
        assert!(
            (left.d.z / left.d.x + (0.5f32).tan()).abs() < 1e-5,
            "{:?}",
            left.d
        );
        // Row 0 is the top: its rays point up.
        assert!(c.ray(2.5, 0.5).d.y > 0.0);
    }

    #[test]
    fn a_near_plane_starts_rays_on_it_and_leaves_their_directions() {
        let eye = Vec3A::new(1.0, 2.0, 3.0);
        let c =
            Camera::look_at(eye, Vec3A::new(1.0, 2.0, 0.0), Vec3A::Y, 1.2, 8, 6).expect("a basis");
        let clipped = c.clone().with_near(0.5);
        for (x, y) in [(4.0, 3.0), (0.0, 0.0), (8.0, 6.0), (1.25, 5.5)] {
            let (r, k) = (c.ray(x, y), clipped.ray(x, y));
            // Without a plane the origin is the eye's bits; with one, half a unit deep.
            assert_eq!(r.o, eye);
            assert_eq!(k.d, r.d);
            assert!(((k.o - eye).dot(-Vec3A::Z) - 0.5).abs() < 1e-6, "{:?}", k.o);
            assert!(
                (k.o - eye).cross(r.d).length() < 1e-6,
                "off the ray: {:?}",
                k.o
            );
        }
        // Not finite or not positive: no plane.
        for near in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert_eq!(c.clone().with_near(near).ray(1.0, 1.0).o, eye);
        }
        let o = Camera::orthographic(eye, -Vec3A::Z, Vec3A::Y, (2.0, 1.5), 8, 6)
            .expect("a basis")
            .with_near(2.0);
        assert!((o.ray(4.0, 3.0).o - Vec3A::new(1.0, 2.0, 1.0)).length() < 1e-6);
    }

    #[test]
    fn a_far_plane_limits_the_first_segment_to_its_depth() {
        let eye = Vec3A::new(0.0, 0.0, 3.0);
        let c = Camera::look_at(eye, Vec3A::ZERO, Vec3A::Y, 1.2, 8, 6)
            .expect("a basis")
            .with_near(0.5)
            .with_far(10.0);
        assert!(c.clips_far());
        for (x, y) in [(4.0, 3.0), (0.0, 0.0), (8.0, 6.0)] {
            let r = c.ray(x, y);
            // The far plane's point on this ray is 10 deep along the axis (−z).
            let end = r.o + r.d * c.far_t(r.d);
            assert!(((eye - end).dot(Vec3A::Z) - 10.0).abs() < 1e-4, "{end:?}");
        }
        // No plane, or one not beyond the near plane: nothing is clipped.
        let open = c.clone().with_far(f32::INFINITY);
        assert!(!open.clips_far() && open.far_t(Vec3A::NEG_Z) == f32::INFINITY);
        assert!(!c.with_far(0.25).clips_far());
    }

    #[test]
    fn orthographic_rays_are_parallel_and_span_the_magnification() {
        let c = Camera::orthographic(
            Vec3A::new(0.0, 0.0, 5.0),
            -Vec3A::Z,
            Vec3A::Y,
            (2.0, 1.0),
            200,
            100,
        )
        .expect("a camera");
        let (tl, br) = (c.ray(0.0, 0.0), c.ray(200.0, 100.0));
        assert_eq!((tl.d, br.d), (-Vec3A::Z, -Vec3A::Z));
        assert!(
            (tl.o - Vec3A::new(-2.0, 1.0, 5.0)).length() < 1e-6,
            "{}",
            tl.o
        );
        assert!(
            (br.o - Vec3A::new(2.0, -1.0, 5.0)).length() < 1e-6,
            "{}",
            br.o
        );
        assert!(Camera::orthographic(Vec3A::ZERO, -Vec3A::Z, Vec3A::Y, (0.0, 1.0), 2, 2).is_none());
    }

    #[test]
    fn look_at_fov_spans_the_film_edges() {
        let fov = 40f32.to_radians();
        let c = Camera::look_at(
            Vec3A::new(0.0, 0.0, 4.0),
            Vec3A::ZERO,
            Vec3A::Y,
            fov,
            64,
            64,
        )
        .expect("valid");
        let edge = c.ray(0.0, 32.0).d;
        let angle = edge.dot(-Vec3A::Z).acos();
        assert!((angle - fov / 2.0).abs() < 1e-5);
        assert!(edge.x < 0.0, "x grows to the right of the image");
        assert!(Camera::look_at(Vec3A::ZERO, Vec3A::Y, Vec3A::Y, fov, 4, 4).is_none());
    }
}
