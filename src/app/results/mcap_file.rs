//! The MCAP file of a recording (`--mcap`, issue 57), written with the `mcap` crate directly:
//! the recorder encodes each message once into a reused buffer and hands the bytes here, so the
//! file costs a channel lookup by id and zstd per message, not the Foxglove SDK's per-message
//! path (its sink set, locks and per-channel maps; see `docs/mcap.md`, "Cost"). The live
//! `--foxglove` server stays on the SDK.
//!
//! Format: <https://mcap.dev/spec> (zstd chunks, message indexes, a summary with chunk indexes
//! and statistics); the file is written as `.NAME.partial` beside its final name and renamed into
//! place by [`McapFile::finish`], like every other output.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// Target uncompressed size of a chunk [bytes]: a few hundred log ticks of 1,000 vehicles fill
/// one, so the chunk and message indexes stay small and zstd works on long runs of similar
/// messages; Foxglove reads a chunk at a time when it seeks.
const CHUNK_SIZE: u64 = 4 << 20;

/// zstd level of the chunks: level 1 takes a third of the default level's time for a slightly
/// larger file.
const ZSTD_LEVEL: u32 = 1;

/// An MCAP file being written under a temporary name: channels by id, messages appended in log
/// time order. A write error is kept and reported by [`McapFile::finish`] (the recording goes
/// on, as the SDK's sink did); dropped unfinished, the temporary file is removed.
pub struct McapFile {
    writer: Option<mcap::Writer<BufWriter<File>>>,
    tmp: PathBuf,
    path: PathBuf,
    /// Schema ids by name.
    schemas: BTreeMap<String, u16>,
    /// Next sequence number per channel id.
    sequences: Vec<u32>,
    error: Option<String>,
}

/// The hidden temporary name of an output beside `path` (`dir/.name.partial`).
pub fn partial_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "run.mcap".into());
    path.with_file_name(format!(".{name}.partial"))
}

impl McapFile {
    /// Start the file for `path` (written to [`partial_path`] until [`McapFile::finish`]) with
    /// the MCAP `profile` (`""`, or `"ros2"`).
    pub fn create(path: &Path, profile: &str) -> Result<McapFile, String> {
        let tmp = partial_path(path);
        // A stale partial file from a run that was killed is overwritten.
        let file = File::create(&tmp).map_err(|e| e.to_string())?;
        let options = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_level(ZSTD_LEVEL)
            // zstd on this thread: the recorder already runs beside the simulation, and worker
            // threads of zstd's own would compete with the simulation's.
            .compression_threads(0)
            .chunk_size(Some(CHUNK_SIZE))
            .profile(profile)
            .library(format!("smlworld {}", env!("CARGO_PKG_VERSION")));
        let writer = options.create(BufWriter::with_capacity(1 << 20, file)).map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            e.to_string()
        })?;
        Ok(McapFile {
            writer: Some(writer),
            tmp,
            path: path.to_path_buf(),
            schemas: BTreeMap::new(),
            sequences: Vec::new(),
            error: None,
        })
    }

    /// The final path of the file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn keep_error(&mut self, e: impl std::fmt::Display) {
        if self.error.is_none() {
            self.error = Some(e.to_string());
        }
    }

    /// A channel on `topic` with `message_encoding` and `schema` (name, encoding, data; the same
    /// schema is written once). After a write error, channel 0 (messages to it are dropped).
    pub fn channel(&mut self, topic: &str, message_encoding: &str, schema: Option<(&str, &str, &[u8])>) -> u16 {
        let Some(writer) = self.writer.as_mut() else { return 0 };
        let schema_id = match schema {
            None => Ok(0),
            Some((name, encoding, data)) => match self.schemas.get(name) {
                Some(&id) => Ok(id),
                None => writer.add_schema(name, encoding, data).inspect(|&id| {
                    self.schemas.insert(name.to_string(), id);
                }),
            },
        };
        match schema_id.and_then(|s| writer.add_channel(s, topic, message_encoding, &BTreeMap::new())) {
            Ok(id) => id,
            Err(e) => {
                self.keep_error(format!("channel {topic}: {e}"));
                0
            }
        }
    }

    /// Append `data` to `channel` at `log_time` \[ns\] (also its publish time).
    pub fn write(&mut self, channel: u16, log_time: u64, data: &[u8]) {
        if channel == 0 || self.error.is_some() {
            return;
        }
        let Some(writer) = self.writer.as_mut() else { return };
        let i = channel as usize;
        if self.sequences.len() <= i {
            self.sequences.resize(i + 1, 0);
        }
        self.sequences[i] += 1;
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: self.sequences[i],
            log_time,
            publish_time: log_time,
        };
        if let Err(e) = writer.write_to_known_channel(&header, data) {
            self.keep_error(e);
        }
    }

    /// Write the summary, close the file and rename it into place; the first error of the
    /// recording, if any.
    pub fn finish(mut self) -> Result<PathBuf, String> {
        let Some(mut writer) = self.writer.take() else { return Err("the file was closed".into()) };
        if let Some(e) = self.error.take() {
            drop(writer);
            let _ = std::fs::remove_file(&self.tmp);
            return Err(e);
        }
        let closed = writer.finish().map_err(|e| e.to_string()).and_then(|_| {
            use std::io::Write as _;
            writer.into_inner().flush().map_err(|e| e.to_string())
        });
        if let Err(e) = closed {
            let _ = std::fs::remove_file(&self.tmp);
            return Err(e);
        }
        std::fs::rename(&self.tmp, &self.path).map_err(|e| format!("cannot move it into place: {e}"))?;
        Ok(self.path.clone())
    }
}

impl Drop for McapFile {
    /// A run that fails: the temporary file is removed.
    fn drop(&mut self) {
        if let Some(writer) = self.writer.take() {
            drop(writer);
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_is_renamed_into_place_with_its_messages_and_removed_when_dropped() {
        let dir = std::env::temp_dir().join(format!("smlworld-mcap-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.mcap");
        let mut file = McapFile::create(&path, "").unwrap();
        let ch = file.channel("/x", "json", Some(("s", "jsonschema", b"{}")));
        let again = file.channel("/y", "json", Some(("s", "jsonschema", b"{}")));
        assert_ne!(ch, 0);
        assert_ne!(ch, again);
        file.write(ch, 5, b"{\"a\":1}");
        file.write(again, 7, b"{}");
        assert!(partial_path(&path).exists() && !path.exists());
        assert_eq!(file.finish().unwrap(), path);
        let bytes = std::fs::read(&path).unwrap();
        let stream: Vec<_> = mcap::MessageStream::new(&bytes).unwrap().map(|m| m.unwrap()).collect();
        assert_eq!(stream.len(), 2);
        assert_eq!(
            (stream[0].channel.topic.as_str(), stream[0].log_time, &stream[0].data[..]),
            ("/x", 5, &b"{\"a\":1}"[..])
        );
        assert_eq!(stream[1].channel.schema.as_ref().map(|s| s.name.as_str()), Some("s"));

        let dropped = dir.join("b.mcap");
        let mut file = McapFile::create(&dropped, "").unwrap();
        let ch = file.channel("/x", "json", None);
        file.write(ch, 1, b"{}");
        drop(file);
        assert!(!partial_path(&dropped).exists() && !dropped.exists());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
