use super::*;
use glam::Vec2;

/// A PNG of `w × h` 8-bit RGB pixels (rows from the top), encoded with the
/// `png` crate (an encoder other than the decoder under test).
pub(crate) fn png_rgb8(w: u32, h: u32, rgb: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc.write_header().unwrap();
    wr.write_image_data(rgb).unwrap();
    wr.finish().unwrap();
    out
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// A PNG signature and IHDR claiming `w × h` RGB, and nothing else.
fn png_header_only(w: u32, h: u32) -> Vec<u8> {
    let mut chunk = b"IHDR".to_vec();
    chunk.extend_from_slice(&w.to_be_bytes());
    chunk.extend_from_slice(&h.to_be_bytes());
    chunk.extend_from_slice(&[8, 2, 0, 0, 0]);
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    out.extend_from_slice(&13u32.to_be_bytes());
    out.extend_from_slice(&chunk);
    out.extend_from_slice(&crc32(&chunk).to_be_bytes());
    out
}

#[test]
fn png_is_srgb_decoded_rows_from_the_top() {
    let rgb = [0u8, 128, 255, 10, 20, 30, 200, 100, 50, 255, 255, 255];
    let t = Texture::decode(&png_rgb8(2, 2, &rgb)).unwrap();
    let l = &t.levels[0];
    assert_eq!((l.width, l.height), (2, 2));
    for (k, px) in rgb.chunks(3).enumerate() {
        let expect =
            Vec3::from_array([0, 1, 2].map(|c| srgb_to_linear(f64::from(px[c]) / 255.0) as f32));
        assert_eq!(l.texels[k], expect, "texel {k}");
    }
    // The spec's two branches and its end points.
    assert_eq!(srgb_to_linear(0.0), 0.0);
    assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-12);
    assert!((srgb_to_linear(0.04) - 0.04 / 12.92).abs() < 1e-15);
    assert!((srgb_to_linear(0.5) - 0.214_041_140_5).abs() < 1e-9);
    // Level 1 is the mean of the four (1 × 1).
    assert_eq!(t.levels.len(), 2);
    let mean = l.texels.iter().map(|t| t.as_dvec3()).sum::<glam::DVec3>() / 4.0;
    assert!((t.levels[1].texels[0].as_dvec3() - mean).length() < 1e-7);
}

#[test]
fn huge_header_is_refused_before_decoding() {
    let e = Texture::decode(&png_header_only(100_000, 100_000)).unwrap_err();
    assert_eq!(
        e,
        TextureError::TooLarge {
            width: 100_000,
            height: 100_000
        }
    );
    // Within each side but too many texels.
    assert!(matches!(
        Texture::decode(&png_header_only(16_384, 2_000)),
        Err(TextureError::TooLarge { .. })
    ));
    assert_eq!(
        Texture::decode_within(&png_header_only(4, 4), 15),
        Err(TextureError::OverBudget {
            width: 4,
            height: 4,
            left: 15
        })
    );
    // A size that passes the bound but a file cut after its header.
    assert!(matches!(
        Texture::decode(&png_header_only(4, 4)),
        Err(TextureError::Decode(_))
    ));
    assert_eq!(Texture::decode(b"GIF89a...."), Err(TextureError::Format));
    assert_eq!(Texture::decode(b""), Err(TextureError::Format));
}

#[test]
fn jpeg_and_exr_decode() {
    // JPEG: a flat colour survives compression to within a code or two.
    let mut jpg = Vec::new();
    let img = image::RgbImage::from_pixel(16, 8, image::Rgb([200, 100, 50]));
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpg, 95)
        .encode_image(&img)
        .unwrap();
    let t = Texture::decode(&jpg).unwrap();
    assert_eq!((t.levels[0].width, t.levels[0].height), (16, 8));
    let expect = Vec3::from_array([200.0, 100.0, 50.0].map(|c| srgb_to_linear(c / 255.0) as f32));
    for t in &t.levels[0].texels {
        assert!((*t - expect).abs().max_element() < 0.02, "{t} vs {expect}");
    }
    // EXR: linear values kept as they are (no sRGB curve), rows from the top.
    use exr::prelude::*;
    let mut bytes = Vec::new();
    SpecificChannels::rgb(|p: exr::math::Vec2<usize>| {
        (p.x() as f32 * 2.5, p.y() as f32 + 0.25, 7.0f32)
    })
    .pipe(|ch| Image::from_channels((3, 2), ch))
    .write()
    .to_buffered(std::io::Cursor::new(&mut bytes))
    .unwrap();
    let t = Texture::decode(&bytes).unwrap();
    let l = &t.levels[0];
    assert_eq!((l.width, l.height), (3, 2));
    assert_eq!(l.at(2, 1), Vec3::new(5.0, 1.25, 7.0));
    assert_eq!(l.at(1, 0), Vec3::new(2.5, 0.25, 7.0));
}

trait Pipe: Sized {
    fn pipe<T>(self, f: impl FnOnce(Self) -> T) -> T {
        f(self)
    }
}
impl<T> Pipe for T {}

#[test]
fn mip_levels_are_box_filtered_and_odd_sides_fold_in() {
    // 5 × 3 texels with values k: level 1 is 2 × 1, its texels the means of
    // columns {0,1} and {2,3,4} over all 3 rows; level 2 is 1 × 1, the mean.
    let texels: Vec<Vec3> = (0..15).map(|k| Vec3::splat(k as f32)).collect();
    let t = Texture::from_texels(5, 3, texels);
    let sizes: Vec<_> = t.levels.iter().map(|l| (l.width, l.height)).collect();
    assert_eq!(sizes, vec![(5, 3), (2, 1), (1, 1)]);
    let mean = |ks: &[u32]| ks.iter().map(|&k| k as f32).sum::<f32>() / ks.len() as f32;
    assert_eq!(t.levels[1].texels[0].x, mean(&[0, 1, 5, 6, 10, 11]));
    assert_eq!(
        t.levels[1].texels[1].x,
        mean(&[2, 3, 4, 7, 8, 9, 12, 13, 14])
    );
    assert_eq!(
        t.levels[2].texels[0].x,
        (mean(&[0, 1, 5, 6, 10, 11]) + mean(&[2, 3, 4, 7, 8, 9, 12, 13, 14])) / 2.0
    );
    assert_eq!(t.memory_bytes(), (15 + 2 + 1) * 12);
}

#[test]
fn bilinear_between_texel_centres_with_repeat_and_clamp() {
    // 2 × 2: top row a b, bottom row c d.
    let (a, b, c, d) = (1.0, 2.0, 4.0, 8.0);
    let t = Texture::from_texels(2, 2, [a, b, c, d].map(Vec3::splat).to_vec());
    let s = |u: f32, v: f32, wrap| t.sample(Vec2::new(u, v), 0.0, wrap).x;
    for wrap in [Wrap::Repeat, Wrap::Clamp] {
        // Texel centres: v = 0.75 is the top row.
        assert_eq!(s(0.25, 0.75, wrap), a);
        assert_eq!(s(0.75, 0.75, wrap), b);
        assert_eq!(s(0.25, 0.25, wrap), c);
        assert_eq!(s(0.75, 0.25, wrap), d);
        // The middle: the mean of the four.
        assert_eq!(s(0.5, 0.5, wrap), (a + b + c + d) / 4.0);
        // A quarter of the way from a to b.
        assert_eq!(s(0.375, 0.75, wrap), a + (b - a) * 0.25);
    }
    // At u = 0 repeat blends the last column with the first; clamp holds.
    assert_eq!(s(0.0, 0.75, Wrap::Repeat), (a + b) / 2.0);
    assert_eq!(s(0.0, 0.75, Wrap::Clamp), a);
    assert_eq!(s(-3.75, 0.75, Wrap::Repeat), a);
    assert_eq!(s(7.0, -9.0, Wrap::Clamp), d);
    // Level of detail: 1 is the 1 × 1 mean, 0.5 halfway, beyond clamps.
    let mean = (a + b + c + d) / 4.0;
    let at = |lod| t.sample(Vec2::new(0.25, 0.75), lod, Wrap::Repeat).x;
    assert_eq!(at(1.0), mean);
    assert_eq!(at(0.5), a + (mean - a) * 0.5);
    assert_eq!(at(40.0), mean);
    assert_eq!(at(f32::NAN), a);
    assert_eq!(at(-3.0), a);
    // Non-finite coordinates do not panic.
    assert!(t
        .sample(Vec2::new(f32::INFINITY, f32::NAN), 0.0, Wrap::Repeat)
        .is_finite());
}
