//! Debug PNGs of camera images (`[render] debug_png_every`): every n-th image of each
//! topic goes to `<run>/images/<topic with / as _>/<stamp ns>.png`; colour as it is,
//! depth colourized (near red → far blue over 0.3..10 m, black = no measurement).

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use vinebench_msgs::{ImageEncoding, ImageMsg};

/// Writes every n-th image of each topic as PNG.
#[derive(Debug)]
pub struct PngDump {
    dir: PathBuf,
    every: u64,
    seen: BTreeMap<String, u64>,
    /// Files written.
    pub written: u64,
}

/// Near end of the depth colour scale, m.
const DEPTH_NEAR_M: f32 = 0.3;
/// Far end of the depth colour scale, m.
const DEPTH_FAR_M: f32 = 10.0;

impl PngDump {
    /// Dumps every `every`-th image (≥ 1) under `dir`.
    pub fn new(dir: &Path, every: u32) -> PngDump {
        PngDump {
            dir: dir.to_path_buf(),
            every: u64::from(every.max(1)),
            seen: BTreeMap::new(),
            written: 0,
        }
    }

    /// The folder images go to.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Takes one image; writes it if it is one to keep.
    pub fn push(&mut self, img: &ImageMsg) -> std::io::Result<()> {
        let n = self.seen.entry(img.topic.to_string()).or_default();
        let keep = n.is_multiple_of(self.every);
        *n += 1;
        if !keep {
            return Ok(());
        }
        let folder = self
            .dir
            .join(img.topic.trim_start_matches('/').replace('/', "_"));
        std::fs::create_dir_all(&folder)?;
        let path = folder.join(format!("{}.png", img.stamp.0));
        write_png(&path, img)?;
        self.written += 1;
        Ok(())
    }
}

/// Writes an image message as an 8-bit PNG (depth colourized).
pub fn write_png(path: &Path, img: &ImageMsg) -> std::io::Result<()> {
    let file = std::fs::File::create(path)?;
    let mut enc = png::Encoder::new(BufWriter::new(file), img.width, img.height);
    enc.set_depth(png::BitDepth::Eight);
    let colourized;
    let data: &[u8] = match img.encoding {
        ImageEncoding::Rgb8 => {
            enc.set_color(png::ColorType::Rgb);
            &img.data
        }
        ImageEncoding::Mono8 => {
            enc.set_color(png::ColorType::Grayscale);
            &img.data
        }
        ImageEncoding::Depth16Mm => {
            enc.set_color(png::ColorType::Rgb);
            colourized = img
                .data
                .chunks_exact(2)
                .flat_map(|b| depth_colour(u16::from_le_bytes([b[0], b[1]])))
                .collect::<Vec<u8>>();
            &colourized
        }
    };
    let mut w = enc.write_header().map_err(std::io::Error::other)?;
    w.write_image_data(data).map_err(std::io::Error::other)?;
    w.finish().map_err(std::io::Error::other)
}

/// Colour of a depth in mm: black for 0, else a red → yellow → green → cyan → blue ramp
/// over 0.3..10 m on a log scale.
pub fn depth_colour(mm: u16) -> [u8; 3] {
    if mm == 0 {
        return [0, 0, 0];
    }
    let z = f32::from(mm) * 1e-3;
    let f = ((z / DEPTH_NEAR_M).ln() / (DEPTH_FAR_M / DEPTH_NEAR_M).ln()).clamp(0.0, 1.0);
    let h = f * 4.0;
    let (r, g, b) = match h as u32 {
        0 => (1.0, h, 0.0),
        1 => (2.0 - h, 1.0, 0.0),
        2 => (0.0, 1.0, h - 2.0),
        _ => (0.0, (4.0 - h).max(0.0), 1.0),
    };
    [(r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8]
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use vinebench_msgs::{FrameId, Nanos};

    #[test]
    fn png_reads_back_with_the_same_pixels() {
        let dir = tempfile::tempdir().unwrap();
        let data: Vec<u8> = (0..4 * 3 * 3).map(|i| (i * 7) as u8).collect();
        let img = ImageMsg {
            stamp: Nanos(1),
            topic: Arc::from("/cam/color/image_raw"),
            frame_id: FrameId::new("cam"),
            width: 4,
            height: 3,
            encoding: ImageEncoding::Rgb8,
            data: Arc::from(data.clone()),
        };
        let p = dir.path().join("a.png");
        write_png(&p, &img).unwrap();
        let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&p).unwrap()));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size().unwrap()];
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (4, 3));
        assert_eq!(&buf[..info.buffer_size()], &data[..]);
    }

    #[test]
    fn every_nth_image_per_topic_is_kept() {
        let dir = tempfile::tempdir().unwrap();
        let mut dump = PngDump::new(dir.path(), 3);
        for k in 0..7 {
            for topic in ["/a/depth", "/b/depth"] {
                let img = ImageMsg {
                    stamp: Nanos(k),
                    topic: Arc::from(topic),
                    frame_id: FrameId::new("cam"),
                    width: 2,
                    height: 2,
                    encoding: ImageEncoding::Depth16Mm,
                    data: Arc::from(vec![0u8, 0, 0xe8, 0x03, 0x10, 0x27, 0xff, 0xff]),
                };
                dump.push(&img).unwrap();
            }
        }
        // Images 0, 3, 6 of each topic.
        assert_eq!(dump.written, 6);
        assert!(dir.path().join("a_depth/3.png").exists());
        assert!(!dir.path().join("a_depth/4.png").exists());
    }

    #[test]
    fn depth_colours_run_from_red_to_blue_and_black_for_none() {
        assert_eq!(depth_colour(0), [0, 0, 0]);
        assert_eq!(depth_colour(300), [255, 0, 0]);
        assert_eq!(depth_colour(10_000), [0, 0, 255]);
        assert_eq!(depth_colour(60_000), [0, 0, 255]);
    }
}
