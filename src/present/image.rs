//! An RGB image and its PNG: what the renders and the shaded maps write.

/// An RGB image, row-major from the top.
#[derive(Debug, Clone)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// Writes an RGB PNG (through a temporary file).
pub(crate) fn write_png(path: &std::path::Path, image: &Image) -> anyhow::Result<()> {
    Ok(crate::plumbing::output::write_atomically(path, |file| {
        let mut enc = png::Encoder::new(file, image.width, image.height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()?.write_image_data(&image.rgb)?;
        Ok(())
    })?)
}
