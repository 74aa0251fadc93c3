//! The checks every builder applies to a parsed value, each answering with the key path of
//! what is wrong: a transform that can be inverted here, the value checks (finite, positive, a
//! colour, keys that do not apply) from [`crate::util::fields`], which the materials share.

use glam::{Affine3A, Mat3, Vec3};

use super::{KeyPath, TransformDesc};
pub(super) use crate::util::fields::{
    color, finite, finite3, only, positive, required, root, Invalid,
};

pub(super) fn build_transform(t: &TransformDesc, path: &KeyPath) -> Result<Affine3A, Invalid> {
    let m = if let Some(rows) = t.matrix {
        if t.translate.is_some() || t.rotate.is_some() || t.scale.is_some() {
            return Err((
                path.key("matrix"),
                "give either `matrix` or translate/rotate/scale, not both".into(),
            ));
        }
        for (r, row) in rows.iter().enumerate() {
            for (c, x) in row.iter().enumerate() {
                if !x.is_finite() {
                    return Err((
                        path.key("matrix").index(r),
                        format!("element {c} must be finite, got {x}"),
                    ));
                }
            }
        }
        if rows[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err((
                path.key("matrix").index(3),
                format!(
                    "the last row of an affine matrix must be [0, 0, 0, 1], got {:?}",
                    rows[3]
                ),
            ));
        }
        let col = |c: usize| Vec3::new(rows[0][c], rows[1][c], rows[2][c]);
        Affine3A::from_mat3_translation(Mat3::from_cols(col(0), col(1), col(2)), col(3))
    } else {
        let mut m = Affine3A::IDENTITY;
        if let Some(s) = t.scale {
            let s = finite3(s, &path.key("scale"))?;
            m = Affine3A::from_scale(s.into()) * m;
        }
        if let Some(r) = &t.rotate {
            let rp = path.key("rotate");
            let axis = finite3(r.axis, &rp.key("axis"))?;
            let axis = axis
                .try_normalize()
                .ok_or_else(|| (rp.key("axis"), "rotation axis must not be zero".to_string()))?;
            let deg = finite(r.degrees, &rp.key("degrees"))?;
            // In f64, rounded once: f32 `sin_cos` is picked per CPU at load time and may round
            // differently, and every worker must build the same geometry bits.
            let r = glam::DMat3::from_axis_angle(axis.as_dvec3(), f64::from(deg).to_radians());
            let r = Mat3::from_cols(r.x_axis.as_vec3(), r.y_axis.as_vec3(), r.z_axis.as_vec3());
            m = Affine3A::from_mat3(r) * m;
        }
        if let Some(tr) = t.translate {
            let tr = finite3(tr, &path.key("translate"))?;
            m = Affine3A::from_translation(tr.into()) * m;
        }
        m
    };
    if let Some(det) = degenerate(&m) {
        return Err((
            path.clone(),
            format!("transform is degenerate (determinant {det:e}): it flattens the shape"),
        ));
    }
    Ok(m)
}

/// The determinant of a map that flattens space (or is not finite), which no shape may be
/// placed by; `None` for an invertible one.
pub(super) fn degenerate(m: &Affine3A) -> Option<f32> {
    let lin = m.matrix3;
    let det = lin.determinant();
    let scale = lin.x_axis.length() * lin.y_axis.length() * lin.z_axis.length();
    let bad = !(det.abs() > 1e-6 * scale)
        || !det.is_finite()
        || scale == 0.0
        || !m.translation.is_finite();
    bad.then_some(det)
}

/// Whether the linear part is a rotation times a uniform scale; returns the scale.
pub(super) fn similarity_scale(m: &Affine3A) -> Option<f32> {
    let (x, y, z) = (m.matrix3.x_axis, m.matrix3.y_axis, m.matrix3.z_axis);
    let (lx, ly, lz) = (x.length(), y.length(), z.length());
    let tol = 1e-5 * lx;
    let ortho =
        x.dot(y).abs() <= tol * ly && y.dot(z).abs() <= tol * lz && x.dot(z).abs() <= tol * lz;
    ((lx - ly).abs() <= tol && (lx - lz).abs() <= tol && ortho).then_some(lx)
}
