use super::*;
use crate::texture::{tests::png_rgb8, Texture, MAX_TEXTURE_TEXELS};

/// A two-part OpenEXR file (ZIP, 16 scan lines a block): part 0 is 1 × 1
/// with channels X, Y, Z (so the decoder's layer is part 1), part 1 is
/// written 1 × 1 RGB too and then its header patched to claim
/// `side × side`, with zeros appended for the offset table the claim needs
/// (so the file is as plausible as a real one of that size: about 33 KB
/// for 65,536²). The shape of a real attack on the size check.
pub(crate) fn hostile_two_part_exr(side: i32) -> Vec<u8> {
    use exr::prelude::*;
    let rgb = |_: Vec2<usize>| (0.5f32, 0.25f32, 1.0f32);
    let layer = |name: &str| {
        Layer::new(
            (1, 1),
            LayerAttributes::named(name),
            Encoding::SMALL_LOSSLESS,
            SpecificChannels::rgb(rgb),
        )
    };
    let image = Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions((1, 1))),
        vec![layer("a"), layer("b")],
    );
    let mut bytes = Vec::new();
    image
        .write()
        .to_buffered(std::io::Cursor::new(&mut bytes))
        .unwrap();
    // The second "dataWindow" attribute: name, type "box2i", size 16, then
    // xMin yMin xMax yMax as little-endian i32.
    let key = b"dataWindow\0box2i\0";
    let at: Vec<usize> = bytes
        .windows(key.len())
        .enumerate()
        .filter(|(_, w)| *w == key)
        .map(|(i, _)| i + key.len() + 4)
        .collect();
    assert_eq!(at.len(), 2, "two parts, two data windows");
    // Part 0's channels B, G, R (16 bytes after each name) become X, Y, Z.
    let key = b"channels\0chlist\0";
    let ch = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
    for (k, name) in [b'X', b'Y', b'Z'].into_iter().enumerate() {
        bytes[ch + 18 * k] = name;
    }
    let max = (side - 1).to_le_bytes();
    bytes[at[1] + 8..at[1] + 12].copy_from_slice(&max);
    bytes[at[1] + 12..at[1] + 16].copy_from_slice(&max);
    let chunks = (side as usize).div_ceil(16);
    // Its chunk count too (a multi-part file says it in each header).
    let key = b"chunkCount\0int\0";
    let at: Vec<usize> = bytes
        .windows(key.len())
        .enumerate()
        .filter(|(_, w)| *w == key)
        .map(|(i, _)| i + key.len() + 4)
        .collect();
    assert_eq!(at.len(), 2, "two parts, two chunk counts");
    bytes[at[1]..at[1] + 4].copy_from_slice(&(chunks as i32).to_le_bytes());
    bytes.resize(bytes.len() + 8 * chunks, 0);
    bytes
}

#[test]
fn every_part_of_an_exr_is_probed_and_a_huge_second_part_refused() {
    let bytes = hostile_two_part_exr(65_536);
    assert!(bytes.len() < 40_000, "{} bytes", bytes.len());
    let h = probe(&bytes).unwrap();
    assert_eq!(h.format, ImageFormat::Exr);
    let sizes: Vec<(u64, u64)> = h.parts.iter().map(|p| (p.width, p.height)).collect();
    assert_eq!(sizes, vec![(1, 1), (65_536, 65_536)]);
    assert!(h.parts.iter().all(|p| p.channels == 3 && !p.deep));
    assert_eq!((h.parts[0].rgb, h.parts[1].rgb), (false, true));
    assert_eq!(
        h.check(MAX_TEXTURE_TEXELS),
        Err(TextureError::TooLarge {
            width: 65_536,
            height: 65_536
        })
    );
    // The decoder checks the same before it allocates a pixel (before the
    // fix it checked part 0 only, and the process aborted).
    assert_eq!(
        Texture::decode(&bytes),
        Err(TextureError::TooLarge {
            width: 65_536,
            height: 65_536
        })
    );
}

#[test]
fn the_parts_together_must_fit_the_budget() {
    // 2048² in part 1 is a legal texture alone, but not within 1000 texels.
    let bytes = hostile_two_part_exr(2048);
    let h = probe(&bytes).unwrap();
    assert_eq!(h.check(MAX_TEXTURE_TEXELS), Ok((2048, 2048)));
    assert!(matches!(
        h.check(1000),
        Err(TextureError::OverBudget { left: 1000, .. })
    ));
    assert!(matches!(
        Texture::decode_within(&bytes, 1000),
        Err(TextureError::OverBudget { .. })
    ));
}

#[test]
fn chunks_the_file_cannot_hold_are_refused() {
    // The claim without the offset table it needs: 4096 chunks of 8 bytes
    // announced in a file of a few hundred bytes.
    let mut bytes = hostile_two_part_exr(65_536);
    bytes.truncate(bytes.len() - 8 * 4096);
    let e = probe(&bytes)
        .unwrap()
        .check(MAX_TEXTURE_TEXELS)
        .unwrap_err();
    assert!(e.to_string().contains("chunks"), "{e}");
}

#[test]
fn png_and_jpeg_sizes_come_from_their_headers() {
    let png = png_rgb8(5, 3, &[7; 45]);
    let h = probe(&png).unwrap();
    assert_eq!(h.format, ImageFormat::Png);
    assert_eq!((h.parts[0].width, h.parts[0].height), (5, 3));
    assert_eq!(h.check(MAX_TEXTURE_TEXELS), Ok((5, 3)));
    let mut jpg = Vec::new();
    let img = image::RgbImage::from_pixel(16, 8, image::Rgb([200, 100, 50]));
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpg, 90)
        .encode_image(&img)
        .unwrap();
    let h = probe(&jpg).unwrap();
    assert_eq!(
        (h.format, h.check(MAX_TEXTURE_TEXELS)),
        (ImageFormat::Jpeg, Ok((16, 8)))
    );
    assert_eq!(probe(b"GIF89a...."), Err(TextureError::Format));
    // The MIP chain the decoder makes, counted from the header.
    let t = Texture::decode(&png).unwrap();
    assert_eq!(TextureHeader::decoded_bytes(5, 3), t.memory_bytes());
}
