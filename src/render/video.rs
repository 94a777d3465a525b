//! MP4 video output (`--video FILE.mp4`): H.264 frames from Cisco's OpenH264 encoder (the
//! `openh264` crate, built from source), muxed by the `mp4` crate.
//!
//! A followed view moves its ground in every frame, which defeats GIF's frame differencing (a
//! 60 s followed GIF at 10 Hz and 1280x720 took 459 MB, issue 61); H.264's motion compensation
//! stores such a video in a few MB at full rate and size.
//!
//! The encoder writes Annex B NAL units (each after a `00 00 00 01` start code); MP4 wants them
//! length-prefixed, with the sequence and picture parameter sets (SPS, PPS) in the track's
//! `avcC` box instead of the samples (ISO/IEC 14496-15 §5.3). So the track is added once the
//! first frame has given the SPS and PPS, and each frame's other NAL units become one sample.

use std::io::BufWriter;
use std::path::{Path, PathBuf};

use image::RgbaImage;
use openh264::encoder::{Encoder, EncoderConfig, FrameRate, FrameType, IntraFramePeriod, QpRange, UsageType};
use openh264::formats::{RgbaSliceU8, YUVBuffer};

use super::RenderError;
use super::output::write_error;
use crate::files::AtomicFile;

/// Time units per second of the MP4 track (90 kHz, the usual video clock: 10, 25 and 30 Hz
/// frames are whole numbers of it).
const TIMESCALE: u32 = 90_000;
/// Seconds of video between key frames (where a player can seek to).
const KEY_FRAME_SECONDS: f64 = 2.0;
/// Finest quantiser the rate control may use (0..=51, lower is finer): finer adds size, not
/// legibility, to drawn frames.
const MIN_QP: u8 = 26;
/// NAL unit types (ITU-T H.264 Table 7-1).
const NAL_SPS: u8 = 7;
const NAL_PPS: u8 = 8;

/// An MP4 video written frame by frame, under a temporary name until [`VideoWriter::finish`]
/// renames it into place (dropped unfinished, the temporary file is removed and an earlier video
/// of the same name stays). Frames of odd width or height are padded to even sides (4:2:0
/// chroma covers 2x2 pixels) by repeating the last column or row.
pub struct VideoWriter {
    path: PathBuf,
    file: AtomicFile,
    /// The file until the first frame has given SPS and PPS for the track.
    out: Option<BufWriter<std::fs::File>>,
    mp4: Option<mp4::Mp4Writer<BufWriter<std::fs::File>>>,
    encoder: Encoder,
    /// Size of the frames pushed \[px\].
    size: (u32, u32),
    /// Size encoded: `size` rounded up to even sides \[px\].
    coded: (u32, u32),
    /// Frame duration [1/`TIMESCALE` s].
    duration: u32,
    frames: u64,
    nal: Vec<u8>,
}

impl VideoWriter {
    /// Create `path` for frames of `width` x `height` px shown at `frame_rate` \[Hz\].
    pub fn create(path: &Path, width: u32, height: u32, frame_rate: f64) -> Result<VideoWriter, RenderError> {
        if !(frame_rate.is_finite() && frame_rate > 0.0 && frame_rate <= 1000.0) {
            return Err(write_error(path, format!("frame rate {frame_rate} Hz must be in (0, 1000]")));
        }
        if width == 0 || height == 0 || width > 4096 || height > 4096 {
            return Err(write_error(path, format!("a {width}x{height} px video: each side must be 1..=4096 px")));
        }
        let coded = (width.next_multiple_of(2), height.next_multiple_of(2));
        let key_every = (KEY_FRAME_SECONDS * frame_rate).round().max(1.0) as u32;
        let config = EncoderConfig::new()
            .qp(QpRange::new(MIN_QP, 51))
            .max_frame_rate(FrameRate::from_hz(frame_rate as f32))
            // Drawn frames: flat colours, sharp edges, text.
            .usage_type(UsageType::ScreenContentRealTime)
            // One thread: the same frames give the same file, and the simulation keeps the cores.
            .num_threads(1)
            // Every frame is a sample at its own time: none may be dropped to meet the rate.
            .skip_frames(false)
            .intra_frame_period(IntraFramePeriod::from_num_frames(key_every));
        let encoder = Encoder::with_api_config(openh264::OpenH264API::from_source(), config)
            .map_err(|e| write_error(path, format!("H.264 encoder: {e}")))?;
        let file = AtomicFile::new(path).map_err(|e| write_error(path, e))?;
        let out = std::fs::File::create(file.path()).map_err(|e| write_error(path, e))?;
        Ok(VideoWriter {
            path: path.to_path_buf(),
            file,
            out: Some(BufWriter::new(out)),
            mp4: None,
            encoder,
            size: (width, height),
            coded,
            duration: (f64::from(TIMESCALE) / frame_rate).round().max(1.0) as u32,
            frames: 0,
            nal: Vec::new(),
        })
    }

    /// Append a frame (of the size given to [`VideoWriter::create`]).
    pub fn push(&mut self, image: &RgbaImage) -> Result<(), RenderError> {
        if image.dimensions() != self.size {
            return Err(write_error(
                &self.path,
                format!(
                    "a {}x{} px frame in a {}x{} px video",
                    image.width(),
                    image.height(),
                    self.size.0,
                    self.size.1
                ),
            ));
        }
        let padded;
        let rgba: &[u8] = if self.coded == self.size {
            image.as_raw()
        } else {
            padded = pad_to(image, self.coded);
            padded.as_raw()
        };
        let yuv = YUVBuffer::from_rgba8_source(RgbaSliceU8::new(rgba, (self.coded.0 as usize, self.coded.1 as usize)));
        let stream = self.encoder.encode(&yuv).map_err(|e| write_error(&self.path, format!("H.264 encoder: {e}")))?;
        let is_sync = matches!(stream.frame_type(), FrameType::IDR | FrameType::I);
        let (mut sps, mut pps) = (None, None);
        self.nal.clear();
        for l in 0..stream.num_layers() {
            let Some(layer) = stream.layer(l) else { continue };
            for n in 0..layer.nal_count() {
                let Some(unit) = layer.nal_unit(n).map(strip_start_code).filter(|u| !u.is_empty()) else { continue };
                match unit[0] & 0x1f {
                    NAL_SPS => sps = Some(unit.to_vec()),
                    NAL_PPS => pps = Some(unit.to_vec()),
                    _ => {
                        let len =
                            u32::try_from(unit.len()).map_err(|_| write_error(&self.path, "NAL unit over 4 GB"))?;
                        self.nal.extend_from_slice(&len.to_be_bytes());
                        self.nal.extend_from_slice(unit);
                    }
                }
            }
        }
        if self.mp4.is_none() {
            let (Some(sps), Some(pps)) = (sps, pps) else {
                return Err(write_error(&self.path, "the H.264 encoder's first frame has no SPS/PPS"));
            };
            self.start(sps, pps)?;
        }
        let Some(mp4) = self.mp4.as_mut() else { return Err(write_error(&self.path, "MP4 writer missing")) };
        let sample = mp4::Mp4Sample {
            start_time: self.frames * u64::from(self.duration),
            duration: self.duration,
            rendering_offset: 0,
            is_sync,
            bytes: mp4::Bytes::copy_from_slice(&self.nal),
        };
        mp4.write_sample(1, &sample).map_err(|e| write_error(&self.path, e))?;
        self.frames += 1;
        Ok(())
    }

    /// The MP4 header and the one video track, from the first frame's parameter sets.
    fn start(&mut self, sps: Vec<u8>, pps: Vec<u8>) -> Result<(), RenderError> {
        let out = self.out.take().ok_or_else(|| write_error(&self.path, "video already finished"))?;
        let config = mp4::Mp4Config {
            major_brand: "isom".parse().map_err(|e| write_error(&self.path, e))?,
            minor_version: 512,
            compatible_brands: ["isom", "iso2", "avc1", "mp41"]
                .iter()
                .map(|b| b.parse())
                .collect::<Result<_, _>>()
                .map_err(|e| write_error(&self.path, e))?,
            timescale: TIMESCALE,
        };
        let mut mp4 = mp4::Mp4Writer::write_start(out, &config).map_err(|e| write_error(&self.path, e))?;
        let side = |px: u32| u16::try_from(px).map_err(|_| write_error(&self.path, format!("{px} px too wide")));
        let track = mp4::TrackConfig {
            track_type: mp4::TrackType::Video,
            timescale: TIMESCALE,
            language: "und".into(),
            media_conf: mp4::MediaConfig::AvcConfig(mp4::AvcConfig {
                width: side(self.coded.0)?,
                height: side(self.coded.1)?,
                seq_param_set: sps,
                pic_param_set: pps,
            }),
        };
        mp4.add_track(&track).map_err(|e| write_error(&self.path, e))?;
        self.mp4 = Some(mp4);
        Ok(())
    }

    /// Number of frames written so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// End the video (its index written, the file flushed) and rename it into place; returns the
    /// size written \[bytes\]. A video without frames is an error (an MP4 track needs its
    /// parameter sets, which come with the first frame); the earlier file of the name stays.
    pub fn finish(self) -> Result<u64, RenderError> {
        let VideoWriter { path, file, mp4, .. } = self;
        let Some(mut mp4) = mp4 else {
            return Err(write_error(&path, "no frame was recorded: the video is not written"));
        };
        mp4.write_end().map_err(|e| write_error(&path, e))?;
        let out = mp4.into_writer().into_inner().map_err(|e| write_error(&path, e.error().to_string()))?;
        out.sync_all().map_err(|e| write_error(&path, e))?;
        let bytes = out.metadata().map_or(0, |m| m.len());
        drop(out);
        file.commit().map_err(|e| write_error(&path, e))?;
        Ok(bytes)
    }
}

/// A NAL unit without its Annex B start code (`00 00 01` or `00 00 00 01`).
fn strip_start_code(unit: &[u8]) -> &[u8] {
    match unit {
        [0, 0, 0, 1, rest @ ..] | [0, 0, 1, rest @ ..] => rest,
        _ => unit,
    }
}

/// `image` grown to `size` \[px\] by repeating its last column and row.
fn pad_to(image: &RgbaImage, size: (u32, u32)) -> RgbaImage {
    let (w, h) = image.dimensions();
    RgbaImage::from_fn(size.0, size.1, |x, y| *image.get_pixel(x.min(w - 1), y.min(h - 1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn start_codes_of_both_lengths_are_stripped() {
        assert_eq!(strip_start_code(&[0, 0, 0, 1, 0x67, 1]), &[0x67, 1]);
        assert_eq!(strip_start_code(&[0, 0, 1, 0x68, 2]), &[0x68, 2]);
        assert_eq!(strip_start_code(&[0x65, 3]), &[0x65, 3]);
    }

    #[test]
    fn odd_frames_are_padded_with_their_edge() {
        let mut image = RgbaImage::new(3, 1);
        image.put_pixel(2, 0, image::Rgba([9, 8, 7, 255]));
        let padded = pad_to(&image, (4, 2));
        assert_eq!(padded.dimensions(), (4, 2));
        assert_eq!(padded.get_pixel(3, 0).0, [9, 8, 7, 255]);
        assert_eq!(padded.get_pixel(3, 1).0, [9, 8, 7, 255]);
        assert_eq!(padded.get_pixel(0, 1).0, [0, 0, 0, 0]);
    }
}
