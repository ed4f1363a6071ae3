//! PNG files of the dataset formats: camera images as 8-bit RGB, coarse masks as 8-bit
//! grayscale label maps (0 background, k = k-th object). Decoding checks the whole file, so
//! a truncated or corrupt PNG is caught here, with the file named, not deep inside lerobot.

use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::Path;

use png::{BitDepth, ColorType, Transformations};

/// An image in row-major order: `channels` bytes per pixel (3 for RGB, 1 for a label map).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub channels: u8,
    /// width * height * channels bytes.
    pub pixels: Vec<u8>,
}

impl Image {
    /// Size as `WxH`, for messages.
    pub fn size(&self) -> String {
        format!("{}x{}", self.width, self.height)
    }

    /// The largest value of a label map (0 for an empty one).
    pub fn max_label(&self) -> u8 {
        self.pixels.iter().copied().max().unwrap_or(0)
    }
}

/// Decodes any 8- or 16-bit PNG file to 8 bits per channel (see [`decode_bytes`]).
fn decode(path: &Path) -> Result<(Image, ColorType), String> {
    let file = File::open(path).map_err(|err| format!("cannot open: {err}"))?;
    decode_reader(BufReader::new(file))
}

/// Decodes PNG bytes to 8 bits per channel; returns the image with its colour type
/// (grayscale, grayscale + alpha, RGB or RGBA; palettes expanded to RGB).
fn decode_bytes(bytes: &[u8]) -> Result<(Image, ColorType), String> {
    if !bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        return Err("not a PNG file (its first bytes are not the PNG signature)".into());
    }
    decode_reader(std::io::Cursor::new(bytes))
}

fn decode_reader(source: impl std::io::BufRead + std::io::Seek) -> Result<(Image, ColorType), String> {
    let mut decoder = png::Decoder::new(source);
    decoder.set_transformations(Transformations::normalize_to_color8());
    let mut reader = decoder.read_info().map_err(|err| format!("not a readable PNG: {err}"))?;
    let size = reader.output_buffer_size().ok_or("the PNG is too large to decode")?;
    let mut pixels = vec![0; size];
    let info = reader.next_frame(&mut pixels).map_err(|err| format!("not a readable PNG: {err}"))?;
    if info.width == 0 || info.height == 0 {
        return Err(format!("the image is {}x{}; it must have pixels", info.width, info.height));
    }
    pixels.truncate(info.buffer_size());
    let channels = info.color_type.samples() as u8;
    Ok((Image { width: info.width, height: info.height, channels, pixels }, info.color_type))
}

/// Reads a camera image as RGB. Grayscale is expanded and alpha dropped (a camera image
/// carries no transparency). The error says what is wrong, without the path.
pub fn read_rgb(path: &Path) -> Result<Image, String> {
    let (image, colour) = decode(path)?;
    let pixels = match colour {
        ColorType::Rgb => return Ok(image),
        ColorType::Rgba => image.pixels.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect(),
        ColorType::Grayscale => image.pixels.iter().flat_map(|&g| [g, g, g]).collect(),
        ColorType::GrayscaleAlpha => image.pixels.chunks_exact(2).flat_map(|p| [p[0], p[0], p[0]]).collect(),
        ColorType::Indexed => return Err("indexed PNG was not expanded".into()),
    };
    Ok(Image { channels: 3, pixels, ..image })
}

/// Reads a label map: 8-bit grayscale, or RGB(A) whose three channels agree everywhere.
pub fn read_label_map(path: &Path) -> Result<Image, String> {
    label_map(decode(path)?)
}

/// A label map from PNG bytes (as [`read_label_map`]).
pub fn label_map_from_png(bytes: &[u8]) -> Result<Image, String> {
    label_map(decode_bytes(bytes)?)
}

fn label_map((image, colour): (Image, ColorType)) -> Result<Image, String> {
    let step = image.channels as usize;
    let pixels: Vec<u8> = match colour {
        ColorType::Grayscale => return Ok(image),
        ColorType::GrayscaleAlpha => image.pixels.iter().step_by(2).copied().collect(),
        ColorType::Rgb | ColorType::Rgba => {
            if image.pixels.chunks_exact(step).any(|p| p[0] != p[1] || p[1] != p[2]) {
                return Err("a label map must be grayscale (one label per pixel), but this PNG has colours".into());
            }
            image.pixels.iter().step_by(step).copied().collect()
        }
        ColorType::Indexed => return Err("indexed PNG was not expanded".into()),
    };
    Ok(Image { channels: 1, pixels, ..image })
}

/// Writes `image` (1 channel: grayscale, 3: RGB) as an 8-bit PNG.
pub fn write_png(path: &Path, image: &Image) -> Result<(), String> {
    let file = File::create(path).map_err(|err| format!("cannot create {}: {err}", path.display()))?;
    encode(BufWriter::new(file), image).map_err(|err| format!("cannot write {}: {err}", path.display()))
}

/// `image` (1 channel: grayscale, 3: RGB) as 8-bit PNG bytes.
pub fn png_bytes(image: &Image) -> Vec<u8> {
    let mut out = Vec::new();
    encode(&mut out, image).expect("an in-memory PNG of a 1- or 3-channel image encodes");
    out
}

fn encode(sink: impl std::io::Write, image: &Image) -> Result<(), String> {
    let colour = match image.channels {
        1 => ColorType::Grayscale,
        3 => ColorType::Rgb,
        other => return Err(format!("cannot write a {other}-channel PNG")),
    };
    let mut encoder = png::Encoder::new(sink, image.width, image.height);
    encoder.set_color(colour);
    encoder.set_depth(BitDepth::Eight);
    encoder.set_compression(png::Compression::Fast);
    let fail = |err: png::EncodingError| err.to_string();
    let mut writer = encoder.write_header().map_err(fail)?;
    writer.write_image_data(&image.pixels).map_err(fail)?;
    writer.finish().map_err(fail)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gradient(channels: u8) -> Image {
        let (width, height) = (5, 3);
        let pixels = (0..width * height * channels as u32).map(|v| (v * 7 % 256) as u8).collect();
        Image { width, height, channels, pixels }
    }

    #[test]
    fn rgb_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.png");
        let image = gradient(3);
        write_png(&path, &image).unwrap();
        assert_eq!(read_rgb(&path).unwrap(), image);
    }

    #[test]
    fn grayscale_reads_as_label_map_and_as_rgb() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.png");
        let labels = gradient(1);
        write_png(&path, &labels).unwrap();
        assert_eq!(read_label_map(&path).unwrap(), labels);
        let rgb = read_rgb(&path).unwrap();
        assert_eq!(rgb.pixels[..3], [labels.pixels[0]; 3]);
    }

    #[test]
    fn coloured_label_map_and_truncated_png_are_rejected() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.png");
        write_png(&path, &gradient(3)).unwrap();
        assert!(read_label_map(&path).unwrap_err().contains("grayscale"));
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
        assert!(read_rgb(&path).unwrap_err().contains("not a readable PNG"));
        std::fs::write(&path, b"not a png").unwrap();
        assert!(read_rgb(&path).unwrap_err().contains("not a readable PNG"));
    }
}
