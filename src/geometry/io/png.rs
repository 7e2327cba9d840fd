//! PNG output of rendered pictures: 8-bit RGB, no interlacing, written with the `png` crate (its deflate is
//! flate2's Rust backend). The same pixels give the same bytes: no time stamp, no text chunk but a fixed
//! `Software` keyword.

use std::path::Path;

use super::FileDigest;
use super::write::write_atomic;
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::raster::Image;

/// `image` as PNG bytes.
///
/// # Errors
/// `internal` when the encoder refuses the image (a zero-sized one, or pixels that do not match its size).
pub fn encode_png(image: &Image) -> Result<Vec<u8>> {
    let mut out = Vec::with_capacity(image.rgb.len() / 8 + 1024);
    encode_into(&mut out, image).map_err(|e| Error::internal(format!("PNG encoding: {e}")))?;
    Ok(out)
}

fn encode_into(out: &mut impl std::io::Write, image: &Image) -> std::result::Result<(), png::EncodingError> {
    let mut enc = png::Encoder::new(out, image.width, image.height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Default);
    enc.set_filter(png::FilterType::Paeth);
    enc.add_text_chunk("Software".into(), "scanstation".into())?;
    let mut w = enc.write_header()?;
    w.write_image_data(&image.rgb)?;
    w.finish()
}

/// Write `image` as a PNG file at `path`, atomically; its size and SHA-256.
///
/// # Errors
/// `input.bad-argument` for an empty image; `resource.output` when the file cannot be written.
pub fn write_png(path: &Path, image: &Image) -> Result<FileDigest> {
    if image.width == 0 || image.height == 0 || image.rgb.len() != 3 * image.width as usize * image.height as usize {
        return Err(Error::new(ErrorCode::InputBadArgument, "an empty or inconsistent image").in_file(path));
    }
    write_atomic(path, |w| encode_into(w, image).map_err(std::io::Error::other))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bytes start with the PNG signature and IHDR of the right size, and repeat exactly.
    #[test]
    fn a_png_has_its_signature_and_size_and_repeats() {
        let mut img = Image::filled(40, 30, [255, 255, 255]);
        img.fill_rect(5, 5, 10, 10, [200, 30, 30]);
        let a = encode_png(&img).unwrap();
        assert_eq!(&a[..8], b"\x89PNG\r\n\x1a\n");
        assert_eq!(&a[12..16], b"IHDR");
        assert_eq!(u32::from_be_bytes(a[16..20].try_into().unwrap()), 40);
        assert_eq!(u32::from_be_bytes(a[20..24].try_into().unwrap()), 30);
        assert_eq!(a, encode_png(&img).unwrap());
        assert!(write_png(Path::new("/tmp/x.png"), &Image { width: 0, height: 0, rgb: vec![] }).is_err());
    }
}
