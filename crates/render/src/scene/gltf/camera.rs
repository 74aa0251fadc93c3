//! The camera of a scene whose `[camera]` is `model = "gltf"`: one a glTF file's node tree
//! places (by name or index, else the first), or, where the file has none, one that frames
//! the scene's bounds.

use glam::Vec3A;

use super::super::check::{only, root, Invalid};
use super::super::{KeyPath, SceneFile};
use super::GltfCamera;
use crate::camera::Camera;
use crate::primitive::Primitive;
use crate::shape::Shape;

/// The camera of a `gltf` camera model: the glTF camera `[camera]` picks by name or by index
/// in its file's `cameras` (by default the lowest index placed), or, with none in the scene,
/// one that frames every finite object from the front (+z), a little above.
pub(in crate::scene) fn camera(
    desc: &SceneFile,
    cameras: &[(KeyPath, GltfCamera)],
    prims: &[Primitive],
    w: u32,
    h: u32,
) -> Result<Camera, Invalid> {
    let aspect = w as f32 / h as f32;
    match chosen(desc, cameras)? {
        Some((path, g)) => placed(path, g, aspect, (w, h)),
        None => framing(prims, aspect, (w, h)),
    }
}

/// The glTF camera `[camera]` names (`name` or `index`), else the first the node tree places;
/// `None` where the files place none.
fn chosen<'c>(
    desc: &SceneFile,
    cameras: &'c [(KeyPath, GltfCamera)],
) -> Result<Option<&'c (KeyPath, GltfCamera)>, Invalid> {
    let cp = root("camera");
    let c = &desc.camera;
    let present = [
        ("eye", c.eye.is_some()),
        ("target", c.target.is_some()),
        ("up", c.up.is_some()),
        ("pitch", c.pitch.is_some()),
        ("yaw", c.yaw.is_some()),
        ("fov", c.fov.is_some()),
        ("name", c.name.is_some()),
        ("index", c.index.is_some()),
    ];
    only(&cp, "a gltf camera", &present, &["name", "index"])?;
    let listed = || {
        let names: Vec<String> = cameras
            .iter()
            .map(|(_, g)| match &g.name {
                Some(n) => format!("{} ({n:?})", g.index),
                None => g.index.to_string(),
            })
            .collect();
        if names.is_empty() {
            "none".to_string()
        } else {
            names.join(", ")
        }
    };
    match (&c.name, c.index) {
        (Some(_), Some(_)) => Err((cp.clone(), "give `name` or `index`, not both".into())),
        (Some(name), None) => cameras
            .iter()
            .find(|(_, g)| g.name.as_deref() == Some(name))
            .map(Some)
            .ok_or_else(|| {
                (
                    cp.key("name"),
                    format!("no glTF camera is named {name:?} (cameras: {})", listed()),
                )
            }),
        (None, Some(i)) => cameras
            .iter()
            .find(|(_, g)| g.index == i)
            .map(Some)
            .ok_or_else(|| {
                (
                    cp.key("index"),
                    format!(
                        "no glTF camera {i} is placed by a node (cameras: {})",
                        listed()
                    ),
                )
            }),
        (None, None) => Ok(cameras.iter().min_by_key(|(_, g)| g.index)),
    }
}

/// glTF camera `g` (its place in its file `path`) on a film of `aspect`: perspective by its vertical field of
/// view, or orthographic.
fn placed(
    path: &KeyPath,
    g: &GltfCamera,
    aspect: f32,
    (w, h): (u32, u32),
) -> Result<Camera, Invalid> {
    let Some(yfov) = g.yfov else {
        // The film keeps its pixels square: the magnification that fits the film's aspect
        // ratio to the camera's height (glTF's xmag is a hint).
        let (_, ymag) = g.mag;
        return Camera::orthographic(g.eye, g.forward, g.up, (ymag * aspect, ymag), w, h)
            .map(|c| c.with_near(g.near).with_far(g.far))
            .ok_or_else(|| {
                (
                    path.clone(),
                    "an orthographic camera needs a positive ymag and a non-degenerate node \
                     transform"
                        .to_string(),
                )
            });
    };
    let fov = 2.0 * ((0.5 * yfov).tan() * aspect).atan();
    if !(fov > 0.0 && fov < std::f32::consts::PI) {
        return Err((path.clone(), format!("yfov {yfov} is out of range")));
    }
    Camera::look_at(g.eye, g.eye + g.forward, g.up, fov, w, h)
        .map(|c| c.with_near(g.near).with_far(g.far))
        .ok_or_else(|| {
            (
                path.clone(),
                "its node's transform is degenerate".to_string(),
            )
        })
}

/// A camera that frames the bounds of `prims` (planes left out) from slightly above, 40°
/// vertically, the bounding sphere fitting the narrower field of view.
fn framing(prims: &[Primitive], aspect: f32, (w, h): (u32, u32)) -> Result<Camera, Invalid> {
    let cp = root("camera");
    let bounds = prims
        .iter()
        .filter(|p| !matches!(p.shape, Shape::Plane { .. }))
        .fold(crate::util::math::Aabb::EMPTY, |b, p| {
            b.union(p.shape.bounds())
        });
    if !(bounds.min.cmple(bounds.max).all()) {
        return Err((
            cp,
            "the scene has no camera and no surface to frame (a glTF file's points and lines are not rendered)".into(),
        ));
    }
    let centre = 0.5 * (bounds.min + bounds.max);
    let radius = (0.5 * (bounds.max - bounds.min).length()).max(1e-3);
    let vfov = 40f32.to_radians();
    let hfov = 2.0 * ((0.5 * vfov).tan() * aspect).atan();
    let fit = vfov.min(hfov);
    let distance = 1.05 * radius / (0.5 * fit).sin();
    let dir = Vec3A::new(0.0, 15f32.to_radians().sin(), 15f32.to_radians().cos());
    let eye = centre + distance * dir;
    Camera::look_at(eye, centre, Vec3A::Y, hfov, w, h)
        .ok_or_else(|| (cp, "the scene's bounds cannot be framed".to_string()))
}
