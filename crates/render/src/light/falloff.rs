//! How a spot light's intensity falls off towards its outer cone: glTF's ramp and Blender's
//! blend, each as a function of the cosine off the spot's axis.

/// How a spot light's intensity falls off towards its outer cone, as a function of the cosine
/// c of the angle off its axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Falloff {
    /// glTF's `KHR_lights_punctual` (and a scene file's `inner_angle`): full inside the inner
    /// cone, then the square of a linear ramp in c to zero at the outer one.
    Gltf {
        /// cos of the inner cone's half-angle.
        cos_inner: f32,
    },
    /// Blender's spot blend, as Cycles renders it: t = (c − cos_outer) / w, clamped to [0, 1],
    /// smoothed to t²(3 − 2t), over a width w = (1 − cos_outer) × blend; a blend of 0 is a hard
    /// edge.
    Blend {
        /// w, in the cosine.
        width: f32,
    },
}

impl Falloff {
    /// The factor at cosine `c` off the axis, for an outer cone of cosine `cos_outer`.
    #[inline]
    pub fn at(self, c: f32, cos_outer: f32) -> f32 {
        match self {
            Falloff::Gltf { cos_inner } => {
                let ramp = ((c - cos_outer) / (cos_inner - cos_outer)).clamp(0.0, 1.0);
                ramp * ramp
            }
            Falloff::Blend { width } => {
                if !(c > cos_outer) {
                    return 0.0;
                }
                let t = if width > 0.0 {
                    ((c - cos_outer) / width).min(1.0)
                } else {
                    1.0
                };
                t * t * (3.0 - 2.0 * t)
            }
        }
    }

    /// The cosine halfway through the falloff, whose cone stands for the spot's in the
    /// estimate of its power.
    pub(super) fn cos_middle(self, cos_outer: f32) -> f32 {
        match self {
            Falloff::Gltf { cos_inner } => 0.5 * (cos_inner + cos_outer),
            Falloff::Blend { width } => cos_outer + 0.5 * width,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spots_falloffs_are_gltfs_ramp_and_blenders_smoothstep() {
        let cos_outer = 0.5;
        let gltf = Falloff::Gltf { cos_inner: 0.9 };
        assert_eq!(gltf.at(0.95, cos_outer), 1.0);
        assert_eq!(
            gltf.at(0.7, cos_outer),
            0.25,
            "the square of the ramp's 0.5"
        );
        assert_eq!(gltf.at(0.5, cos_outer), 0.0);
        // Blender's blend: a smoothstep over (1 − c₀) × blend from the outer cone.
        let soft = Falloff::Blend { width: 0.2 };
        assert_eq!(soft.at(0.5, cos_outer), 0.0);
        assert!(
            (soft.at(0.6, cos_outer) - 0.5).abs() < 1e-6,
            "the smoothstep's middle"
        );
        assert_eq!(soft.at(0.75, cos_outer), 1.0);
        // A blend of 0 is a hard edge: full just inside, nothing on it.
        let hard = Falloff::Blend { width: 0.0 };
        assert_eq!(hard.at(0.5001, cos_outer), 1.0);
        assert_eq!(hard.at(0.5, cos_outer), 0.0);
    }
}
