//! Image textures: a diffuse material's albedo read from a PNG, JPEG or EXR file, looked up
//! at a mesh's texture coordinates with bilinear filtering.
//!
//! 8-bit and 16-bit images hold display-encoded (sRGB) values and are decoded to linear once,
//! at load; EXR files hold linear values already. Texels are clamped to [0, 1]: an albedo above
//! 1 would create energy. Coordinates wrap (repeat), and v runs up the image, as in OBJ files.

use std::io::Cursor;

use glam::{Vec2, Vec3A};

/// A texture in linear RGB, row 0 at the top.
#[derive(Clone, Debug)]
pub struct Texture {
    width: usize,
    height: usize,
    texels: Vec<Vec3A>,
}

/// Which decoder a file name calls for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    /// PNG.
    Png,
    /// JPEG.
    Jpeg,
    /// OpenEXR.
    Exr,
}

impl ImageFormat {
    /// By extension (case-insensitive); `None` for anything else.
    pub fn from_name(name: &str) -> Option<Self> {
        let ext = name.rsplit_once('.')?.1.to_ascii_lowercase();
        match ext.as_str() {
            "png" => Some(Self::Png),
            "jpg" | "jpeg" => Some(Self::Jpeg),
            "exr" => Some(Self::Exr),
            _ => None,
        }
    }
}

/// The sRGB transfer function's inverse (IEC 61966-2-1), in f64 for exact table entries.
pub fn srgb_to_linear(c: f64) -> f64 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

impl Texture {
    /// Decodes `bytes` as `format`, at most `max_texels` texels. The error is one line.
    pub fn decode(bytes: &[u8], format: ImageFormat, max_texels: u64) -> Result<Self, String> {
        let (width, height, texels) = match format {
            ImageFormat::Png | ImageFormat::Jpeg => decode_8_16(bytes, format, max_texels)?,
            ImageFormat::Exr => decode_exr(bytes, max_texels)?,
        };
        if width == 0 || height == 0 {
            return Err("the image is empty".into());
        }
        let texels = texels
            .into_iter()
            .map(|t: [f32; 3]| {
                let t = Vec3A::from(t);
                // NaN becomes 0 (max ignores it), infinities and values above 1 become 1.
                t.max(Vec3A::ZERO).min(Vec3A::ONE)
            })
            .collect();
        Ok(Self {
            width,
            height,
            texels,
        })
    }

    /// A texture of `width` × `height` linear texels, row 0 at the top (for tests).
    pub fn from_texels(width: usize, height: usize, texels: Vec<Vec3A>) -> Self {
        assert_eq!(texels.len(), width * height);
        Self {
            width,
            height,
            texels,
        }
    }

    /// Size in texels.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn texel(&self, x: i64, y: i64) -> Vec3A {
        let x = x.rem_euclid(self.width as i64) as usize;
        let y = y.rem_euclid(self.height as i64) as usize;
        self.texels[y * self.width + x]
    }

    /// The bilinearly filtered value at `uv` (texel centres at half-integers; u right, v up).
    #[inline]
    pub fn lookup(&self, uv: Vec2) -> Vec3A {
        if !uv.is_finite() {
            return self.texel(0, 0);
        }
        // Wrap first, in f64, so that large coordinates keep their fraction.
        let u = f64::from(uv.x).rem_euclid(1.0);
        let v = f64::from(uv.y).rem_euclid(1.0);
        let x = u * self.width as f64 - 0.5;
        let y = (1.0 - v) * self.height as f64 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let top = self.texel(x0, y0) * (1.0 - fx) + self.texel(x0 + 1, y0) * fx;
        let bottom = self.texel(x0, y0 + 1) * (1.0 - fx) + self.texel(x0 + 1, y0 + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

type Decoded = (usize, usize, Vec<[f32; 3]>);

fn check_size(width: u64, height: u64, max_texels: u64) -> Result<(), String> {
    if width.saturating_mul(height) > max_texels {
        return Err(format!(
            "{width}×{height} texels, above the limit of {max_texels}"
        ));
    }
    Ok(())
}

fn decode_8_16(bytes: &[u8], format: ImageFormat, max_texels: u64) -> Result<Decoded, String> {
    let format = match format {
        ImageFormat::Png => image::ImageFormat::Png,
        _ => image::ImageFormat::Jpeg,
    };
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), format);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(max_texels.saturating_mul(16));
    reader.limits(limits);
    let (w, h) = reader
        .into_dimensions()
        .map_err(|e| format!("not a readable image: {e}"))?;
    check_size(u64::from(w), u64::from(h), max_texels)?;
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), format);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(max_texels.saturating_mul(16));
    reader.limits(limits);
    let img = reader
        .decode()
        .map_err(|e| format!("not a readable image: {e}"))?;
    let sixteen = matches!(
        img.color(),
        image::ColorType::L16
            | image::ColorType::La16
            | image::ColorType::Rgb16
            | image::ColorType::Rgba16
    );
    // Every code's linear value, computed once per image rather than once per texel.
    let table = |max: u32| -> Vec<f32> {
        (0..=max)
            .map(|c| srgb_to_linear(f64::from(c) / f64::from(max)) as f32)
            .collect()
    };
    let texels = if sixteen {
        let table = table(65535);
        img.to_rgb16()
            .pixels()
            .map(|p| p.0.map(|c| table[usize::from(c)]))
            .collect()
    } else {
        let table = table(255);
        img.to_rgb8()
            .pixels()
            .map(|p| p.0.map(|c| table[usize::from(c)]))
            .collect()
    };
    Ok((w as usize, h as usize, texels))
}

fn decode_exr(bytes: &[u8], max_texels: u64) -> Result<Decoded, String> {
    use exr::prelude::*;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |res, _| {
                let (w, h) = (res.width(), res.height());
                let texels = if (w as u64).saturating_mul(h as u64) > max_texels {
                    Vec::new()
                } else {
                    vec![[0f32; 3]; w * h]
                };
                (w, h, texels)
            },
            |(w, _, px): &mut (usize, usize, Vec<[f32; 3]>),
             pos,
             (r, g, b, _a): (f32, f32, f32, f32)| {
                if let Some(t) = px.get_mut(pos.y() * *w + pos.x()) {
                    *t = [r, g, b];
                }
            },
        )
        .first_valid_layer()
        .all_attributes()
        .non_parallel()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| format!("not a readable EXR image: {e}"))?;
    let (w, h, texels) = image.layer_data.channel_data.pixels;
    check_size(w as u64, h as u64, max_texels)?;
    Ok((w, h, texels))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_lookup_hits_texel_centres_and_blends_between_them() {
        // 2×2: top row red, green; bottom row blue, white.
        let t = Texture::from_texels(2, 2, vec![Vec3A::X, Vec3A::Y, Vec3A::Z, Vec3A::ONE]);
        // Texel centres: u = 0.25 or 0.75, v = 0.75 (top) or 0.25 (bottom).
        assert_eq!(t.lookup(Vec2::new(0.25, 0.75)), Vec3A::X);
        assert_eq!(t.lookup(Vec2::new(0.75, 0.75)), Vec3A::Y);
        assert_eq!(t.lookup(Vec2::new(0.25, 0.25)), Vec3A::Z);
        assert_eq!(t.lookup(Vec2::new(0.75, 0.25)), Vec3A::ONE);
        // Half way between the top two; and wrapping (u = 1.25 is u = 0.25).
        assert_eq!(t.lookup(Vec2::new(0.5, 0.75)), Vec3A::new(0.5, 0.5, 0.0));
        assert_eq!(t.lookup(Vec2::new(1.25, -0.25)), Vec3A::X);
        // At u = 0 the left and right edge texels blend (repeat addressing).
        assert_eq!(t.lookup(Vec2::new(0.0, 0.75)), Vec3A::new(0.5, 0.5, 0.0));
        assert_eq!(t.lookup(Vec2::new(f32::NAN, 0.5)), Vec3A::X);
    }

    #[test]
    fn srgb_decode_matches_the_standard() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-12);
        // 0.5 encodes about 0.214 linear; the linear segment below 0.04045.
        assert!((srgb_to_linear(0.5) - 0.214_041).abs() < 1e-6);
        assert!((srgb_to_linear(0.04) - 0.04 / 12.92).abs() < 1e-12);
    }

    #[test]
    fn png_and_exr_decode_with_srgb_for_8_bit_only() {
        // A 2×1 8-bit PNG: sRGB 128 and 255.
        let mut png = Vec::new();
        {
            let mut e = png::Encoder::new(&mut png, 2, 1);
            e.set_color(png::ColorType::Rgb);
            e.set_depth(png::BitDepth::Eight);
            let mut w = e.write_header().expect("header");
            w.write_image_data(&[128, 128, 128, 255, 0, 0])
                .expect("data");
        }
        let t = Texture::decode(&png, ImageFormat::Png, 100).expect("png");
        assert_eq!(t.size(), (2, 1));
        let grey = srgb_to_linear(128.0 / 255.0) as f32;
        assert_eq!(t.texels[0], Vec3A::splat(grey));
        assert_eq!(t.texels[1], Vec3A::X);
        assert!(
            Texture::decode(&png, ImageFormat::Png, 1).is_err(),
            "the texel limit"
        );
        assert!(Texture::decode(b"not a png", ImageFormat::Png, 100).is_err());
        assert!(Texture::decode(&png[..20], ImageFormat::Png, 100).is_err());

        // A 2×1 EXR: linear already, clamped to [0, 1].
        use exr::prelude::{Image, SpecificChannels, WritableImage};
        let img = Image::from_channels(
            (2, 1),
            SpecificChannels::rgb(|p: exr::math::Vec2<usize>| {
                (p.x() as f32 * 2.0, 0.5f32, -1.0f32)
            }),
        );
        let mut exr = Cursor::new(Vec::new());
        img.write().to_buffered(&mut exr).expect("exr");
        let t = Texture::decode(exr.get_ref(), ImageFormat::Exr, 100).expect("decodes");
        assert_eq!(
            t.texels,
            [Vec3A::new(0.0, 0.5, 0.0), Vec3A::new(1.0, 0.5, 0.0)]
        );
        assert!(Texture::decode(&exr.get_ref()[..40], ImageFormat::Exr, 100).is_err());
    }

    /// JPEG decodes through the same sRGB table as PNG. Flat 8×8 grey blocks survive JPEG's
    /// transform almost exactly, so each block's texels must be its level decoded from sRGB
    /// (to within a level), and the left and right halves must come out in that order.
    #[test]
    fn jpeg_decodes_with_srgb() {
        let (w, h) = (16u32, 8u32);
        let pixels: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                let level = if i % w < 8 { 64 } else { 200 };
                [level; 3]
            })
            .collect();
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 100)
            .encode(&pixels, w, h, image::ExtendedColorType::Rgb8)
            .expect("encodes");
        let t = Texture::decode(&jpeg, ImageFormat::Jpeg, 1000).expect("decodes");
        assert_eq!(t.size(), (16, 8));
        for (x, level) in [(3usize, 64.0), (12, 200.0)] {
            let got = t.texels[4 * 16 + x];
            for near in [level - 1.0, level + 1.0] {
                let bound = srgb_to_linear(near / 255.0) as f32;
                assert!(
                    if near < level {
                        got.x >= bound
                    } else {
                        got.x <= bound
                    },
                    "texel {x}: {got:?} against sRGB level {level}"
                );
            }
            assert_eq!(got.x, got.y);
            assert_eq!(got.y, got.z);
        }
        assert!(
            Texture::decode(&jpeg, ImageFormat::Jpeg, 100).is_err(),
            "the texel limit"
        );
        assert!(Texture::decode(&jpeg[..60], ImageFormat::Jpeg, 1000).is_err());
    }
}
