//! `[animation]`: a scene file at one frame. The camera's moving fields and the animated
//! objects' transforms are interpolated between the keys around the frame, and written back
//! into a plain scene file, which is then validated and built like any other: an animated scene
//! pays for its keys once per frame and a still scene nothing.
//!
//! Interpolation runs in f64 and is rounded to f32 once, as rotations are in `build.rs`: every
//! worker must build the same geometry bits for the same frame.

use glam::{DAffine3, DQuat, DVec3};

use super::check::{build_transform, Invalid};
use super::format::{
    AnimationDesc, CameraKeyDesc, ObjectKeyDesc, RotateDesc, SceneFile, TransformDesc,
};
use super::KeyPath;

fn root() -> KeyPath {
    KeyPath::default().key("animation")
}

/// The two keys around `frame` and the weight of the second: (i, i + 1, s) with s in [0, 1];
/// before the first key or after the last, that key alone (s = 0).
fn around(frames: &[f64], frame: f64) -> (usize, usize, f64) {
    let last = frames.len() - 1;
    if frame <= frames[0] {
        return (0, 0, 0.0);
    }
    if frame >= frames[last] {
        return (last, last, 0.0);
    }
    let i = frames.partition_point(|&f| f <= frame) - 1;
    let s = (frame - frames[i]) / (frames[i + 1] - frames[i]);
    (i, i + 1, s)
}

/// Checks that keys' frames are finite and strictly increasing, and that there is one.
fn check_frames(frames: &[f64], path: &KeyPath) -> Result<(), Invalid> {
    if frames.is_empty() {
        return Err((path.clone(), "needs at least one key".into()));
    }
    for (i, f) in frames.iter().enumerate() {
        if !f.is_finite() {
            return Err((
                path.index(i).key("frame"),
                format!("must be a finite number, got {f}"),
            ));
        }
        if i > 0 && *f <= frames[i - 1] {
            return Err((
                path.index(i).key("frame"),
                format!(
                    "keys must be in increasing frame order: {f} follows {}",
                    frames[i - 1]
                ),
            ));
        }
    }
    Ok(())
}

fn lerp3(a: [f32; 3], b: [f32; 3], s: f64) -> [f32; 3] {
    let (a, b) = (DVec3::from(a.map(f64::from)), DVec3::from(b.map(f64::from)));
    a.lerp(b, s).as_vec3().into()
}

fn lerp1(a: f32, b: f32, s: f64) -> f32 {
    (f64::from(a) + (f64::from(b) - f64::from(a)) * s) as f32
}

fn finite_all(v: &[f32], path: &KeyPath) -> Result<(), Invalid> {
    match v.iter().find(|x| !x.is_finite()) {
        Some(x) => Err((path.clone(), format!("must be finite, got {x}"))),
        None => Ok(()),
    }
}

/// The camera at `frame`: each field the keys give, interpolated linearly.
fn camera_at(desc: &mut SceneFile, keys: &[CameraKeyDesc], frame: f64) -> Result<(), Invalid> {
    let path = root().key("camera");
    let frames: Vec<f64> = keys.iter().map(|k| k.frame).collect();
    check_frames(&frames, &path)?;
    let fields = |k: &CameraKeyDesc| {
        [
            k.eye.is_some(),
            k.target.is_some(),
            k.up.is_some(),
            k.fov.is_some(),
            k.pitch.is_some(),
            k.yaw.is_some(),
        ]
    };
    for (i, k) in keys.iter().enumerate() {
        if fields(k) != fields(&keys[0]) {
            return Err((
                path.index(i),
                "every camera key must give the same fields (eye, target, up, fov, pitch, yaw) \
                 as the first"
                    .into(),
            ));
        }
        let kp = path.index(i);
        for (name, v) in [("eye", k.eye), ("target", k.target), ("up", k.up)] {
            if let Some(v) = v {
                finite_all(&v, &kp.key(name))?;
            }
        }
        for (name, v) in [("fov", k.fov), ("pitch", k.pitch), ("yaw", k.yaw)] {
            if let Some(v) = v {
                finite_all(&[v], &kp.key(name))?;
            }
        }
    }
    let (a, b, s) = around(&frames, frame);
    let (a, b) = (&keys[a], &keys[b]);
    let c = &mut desc.camera;
    let v3 = |x: Option<[f32; 3]>, y: Option<[f32; 3]>| x.zip(y).map(|(x, y)| lerp3(x, y, s));
    let v1 = |x: Option<f32>, y: Option<f32>| x.zip(y).map(|(x, y)| lerp1(x, y, s));
    c.eye = v3(a.eye, b.eye).or(c.eye);
    c.target = v3(a.target, b.target).or(c.target);
    c.up = v3(a.up, b.up).or(c.up);
    c.fov = v1(a.fov, b.fov).or(c.fov);
    c.pitch = v1(a.pitch, b.pitch).or(c.pitch);
    c.yaw = v1(a.yaw, b.yaw).or(c.yaw);
    Ok(())
}

/// A key's rotation as a unit quaternion (identity when it gives none).
fn rotation(r: &Option<RotateDesc>, path: &KeyPath) -> Result<DQuat, Invalid> {
    let Some(r) = r else {
        return Ok(DQuat::IDENTITY);
    };
    finite_all(&r.axis, &path.key("axis"))?;
    finite_all(&[r.degrees], &path.key("degrees"))?;
    let axis = DVec3::from(r.axis.map(f64::from))
        .try_normalize()
        .ok_or_else(|| {
            (
                path.key("axis"),
                "rotation axis must not be zero".to_string(),
            )
        })?;
    Ok(DQuat::from_axis_angle(
        axis,
        f64::from(r.degrees).to_radians(),
    ))
}

/// The animated part of an object's transform at `frame`: scale, then rotation (slerp), then
/// translation, as in a `transform` table.
fn track_at(keys: &[ObjectKeyDesc], path: &KeyPath, frame: f64) -> Result<DAffine3, Invalid> {
    let frames: Vec<f64> = keys.iter().map(|k| k.frame).collect();
    check_frames(&frames, path)?;
    let mut parts = Vec::with_capacity(keys.len());
    for (i, k) in keys.iter().enumerate() {
        let kp = path.index(i);
        let t = k.translate.unwrap_or([0.0; 3]);
        let sc = k.scale.unwrap_or([1.0; 3]);
        finite_all(&t, &kp.key("translate"))?;
        finite_all(&sc, &kp.key("scale"))?;
        parts.push((t, rotation(&k.rotate, &kp.key("rotate"))?, sc));
    }
    let (a, b, s) = around(&frames, frame);
    let (ta, ra, sa) = parts[a];
    let (tb, rb, sb) = parts[b];
    let t = DVec3::from(lerp3(ta, tb, s).map(f64::from));
    let sc = DVec3::from(lerp3(sa, sb, s).map(f64::from));
    // The shorter way round: q and −q are the same rotation.
    let rb = if ra.dot(rb) < 0.0 { -rb } else { rb };
    let r = if s == 0.0 { ra } else { ra.slerp(rb, s) };
    Ok(DAffine3::from_scale_rotation_translation(sc, r, t))
}

/// `desc` at `frame`, without its `[animation]`: the same file when it has none.
pub(super) fn at_frame(desc: &SceneFile, frame: f64) -> Result<SceneFile, Invalid> {
    let Some(anim) = &desc.animation else {
        return Ok(desc.clone());
    };
    let mut out = desc.clone();
    out.animation = None;
    let AnimationDesc { camera, objects } = anim;
    if !camera.is_empty() {
        camera_at(&mut out, camera, frame)?;
    }
    let mut seen = vec![false; desc.objects.len()];
    for (k, track) in objects.iter().enumerate() {
        let path = root().key("objects").index(k);
        let Some(o) = out.objects.get_mut(track.object) else {
            return Err((
                path.key("object"),
                format!(
                    "object {} does not exist (the scene has {} objects, numbered from 0)",
                    track.object,
                    desc.objects.len()
                ),
            ));
        };
        if std::mem::replace(&mut seen[track.object], true) {
            return Err((
                path.key("object"),
                format!("object {} is animated twice", track.object),
            ));
        }
        let anim = track_at(&track.keys, &path.key("keys"), frame)?;
        let own = match &o.transform {
            Some(t) => {
                let own_path = KeyPath::default().key("objects").index(track.object);
                build_transform(t, &own_path.key("transform"))?
            }
            None => glam::Affine3A::IDENTITY,
        };
        let own = DAffine3::from_mat3_translation(
            own.matrix3.as_dmat3(),
            glam::Vec3::from(own.translation).as_dvec3(),
        );
        let m = anim * own;
        let row = |r: usize| {
            let m3 = m.matrix3.row(r);
            [
                m3.x as f32,
                m3.y as f32,
                m3.z as f32,
                m.translation[r] as f32,
            ]
        };
        o.transform = Some(TransformDesc {
            matrix: Some([row(0), row(1), row(2), [0.0, 0.0, 0.0, 1.0]]),
            ..TransformDesc::default()
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(frame: f64, translate: [f32; 3], degrees: f32) -> ObjectKeyDesc {
        ObjectKeyDesc {
            frame,
            translate: Some(translate),
            rotate: Some(RotateDesc {
                axis: [0.0, 1.0, 0.0],
                degrees,
            }),
            scale: None,
        }
    }

    #[test]
    fn keys_interpolate_linearly_and_rotations_by_slerp_and_hold_outside() {
        let keys = [
            key(1.0, [0.0, 0.0, 0.0], 0.0),
            key(11.0, [2.0, 4.0, -2.0], 90.0),
        ];
        let p = KeyPath::default();
        let mid = track_at(&keys, &p, 6.0).expect("valid");
        assert_eq!(mid.translation, DVec3::new(1.0, 2.0, -1.0));
        let want = DQuat::from_axis_angle(DVec3::Y, 45f64.to_radians());
        let got = DQuat::from_mat3(&mid.matrix3);
        assert!(got.angle_between(want) < 1e-6, "{got:?} vs {want:?}");
        let before = track_at(&keys, &p, -3.0).expect("valid");
        assert_eq!(before, DAffine3::IDENTITY);
        let after = track_at(&keys, &p, 20.0).expect("valid");
        assert_eq!(after.translation, DVec3::new(2.0, 4.0, -2.0));
    }

    #[test]
    fn rotations_take_the_short_way_round() {
        // 350° is −10°: halfway from 0 is −5°, not 175°.
        let keys = [key(0.0, [0.0; 3], 0.0), key(2.0, [0.0; 3], 350.0)];
        let mid = track_at(&keys, &KeyPath::default(), 1.0).expect("valid");
        let want = DQuat::from_axis_angle(DVec3::Y, (-5f64).to_radians());
        assert!(DQuat::from_mat3(&mid.matrix3).angle_between(want) < 1e-6);
    }

    #[test]
    fn bad_keys_are_refused_with_their_path() {
        let p = KeyPath::default().key("keys");
        let (path, msg) = track_at(&[key(2.0, [0.0; 3], 0.0), key(2.0, [0.0; 3], 0.0)], &p, 1.0)
            .expect_err("same frame twice");
        assert_eq!(path, p.index(1).key("frame"));
        assert!(msg.contains("increasing"), "{msg}");
        let (_, msg) = track_at(&[], &p, 1.0).expect_err("no keys");
        assert!(msg.contains("at least one key"), "{msg}");
        let (path, _) = track_at(&[key(f64::NAN, [0.0; 3], 0.0)], &p, 1.0).expect_err("NaN");
        assert_eq!(path, p.index(0).key("frame"));
    }
}
