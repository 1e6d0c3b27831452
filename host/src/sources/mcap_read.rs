//! A streaming reader of MCAP files (the container of ROS 2 recordings):
//! records are read one at a time from the file, so memory holds one
//! chunk, never the recording, and reading stops as soon as the caller has
//! what it asked for.
//!
//! Every length a record announces is checked against the bytes the file
//! (or the enclosing record) has left before it sizes anything; a
//! compressed chunk is decompressed into memory that grows with what the
//! decoder actually produces, up to its declared uncompressed size, itself
//! at most [`MAX_CHUNK_BYTES`]; a chunk's CRC, where its writer computed
//! one, is verified. Errors name the file's byte offset of the record at
//! fault. Schemas, attachments, metadata, indexes and the summary section
//! are skipped (the data section alone is read).

use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom};
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

/// The largest uncompressed chunk read (1 GiB): writers make chunks of a
/// few MiB (a message larger than that gets a chunk of its own); a
/// declared size beyond it is refused before anything is allocated.
pub const MAX_CHUNK_BYTES: u64 = 1 << 30;

/// The magic bytes at both ends of an MCAP file.
const MAGIC: [u8; 8] = [0x89, b'M', b'C', b'A', b'P', b'0', b'\r', b'\n'];

/// Record opcodes read (the others are skipped).
mod op {
    pub const FOOTER: u8 = 0x02;
    pub const CHANNEL: u8 = 0x04;
    pub const MESSAGE: u8 = 0x05;
    pub const CHUNK: u8 = 0x06;
    pub const DATA_END: u8 = 0x0F;
}

/// Why an MCAP file could not be read: the file, the byte offset of the
/// record at fault and what is wrong.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {what}")]
pub struct McapError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong, and where.
    pub what: String,
}

/// A channel: the topic its messages are on and their encoding.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Channel {
    /// The topic.
    pub topic: String,
    /// The messages' encoding (`cdr` for ROS 2).
    pub message_encoding: String,
}

/// One message handed to the caller.
#[derive(Debug)]
pub struct Message<'a> {
    /// Its channel.
    pub channel: &'a Channel,
    /// When it was logged (ns).
    pub log_time: u64,
    /// The serialised message.
    pub data: &'a [u8],
    /// The file's byte offset of the record (of its chunk, for a message
    /// inside one).
    pub offset: u64,
}

/// A little-endian cursor over one record's body; `at` is the file offset
/// its errors name.
struct Body<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Body<'a> {
    fn take(&mut self, n: u64, what: &str) -> Result<&'a [u8], String> {
        let left = self.b.len() - self.pos;
        if n > left as u64 {
            return Err(format!("{what} of {n} bytes, the record has {left} left"));
        }
        let s = &self.b[self.pos..self.pos + n as usize];
        self.pos += n as usize;
        Ok(s)
    }

    fn u16(&mut self, what: &str) -> Result<u16, String> {
        self.take(2, what).map(|b| u16::from_le_bytes([b[0], b[1]]))
    }

    fn u32(&mut self, what: &str) -> Result<u32, String> {
        self.take(4, what).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u64(&mut self, what: &str) -> Result<u64, String> {
        self.take(8, what).map(|b| u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
    }

    fn string(&mut self, what: &str) -> Result<String, String> {
        let n = self.u32(what)?;
        let b = self.take(u64::from(n), what)?;
        std::str::from_utf8(b).map(str::to_owned).map_err(|_| format!("{what} is not UTF-8"))
    }

    fn rest(&mut self) -> &'a [u8] {
        let s = &self.b[self.pos..];
        self.pos = self.b.len();
        s
    }
}

/// How reading a data section ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Ending {
    /// At its end record, or where the caller stopped.
    Complete,
    /// The file is cut short (a recording whose writer stopped without a
    /// footer): every record before `at` was read whole.
    Cut {
        /// The byte offset of the first record not read whole.
        at: u64,
        /// What is missing there.
        what: String,
    },
}

/// Reads an MCAP file's data section, handing each message to `on` until
/// it returns `Break` or the data section ends; a file cut short is read
/// up to its last whole record ([`Ending::Cut`]: the caller says whether
/// that is an error).
pub fn read_messages(
    path: &Path,
    on: impl FnMut(&Message<'_>) -> Result<ControlFlow<()>, String>,
) -> Result<Ending, McapError> {
    let err = |what: String| McapError { path: path.to_owned(), what };
    let file = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
    let size = file.metadata().map_err(|e| err(e.to_string()))?.len();
    read_messages_from(std::io::BufReader::with_capacity(1 << 20, file), size, path, on)
}

/// [`read_messages`] from any source of `size` bytes (`path` names it in
/// errors).
pub fn read_messages_from<R: Read + Seek>(
    mut r: R,
    size: u64,
    path: &Path,
    mut on: impl FnMut(&Message<'_>) -> Result<ControlFlow<()>, String>,
) -> Result<Ending, McapError> {
    let err = |what: String| McapError { path: path.to_owned(), what };
    let mut magic = [0u8; 8];
    if size < 8 || r.read_exact(&mut magic).is_err() || magic != MAGIC {
        return Err(err("not an MCAP file (no MCAP magic at its start)".into()));
    }
    let mut channels: BTreeMap<u16, Channel> = BTreeMap::new();
    let mut pos = 8u64;
    let mut body = Vec::new();
    loop {
        if size - pos < 9 {
            let what = format!("{} bytes, no whole record header (no data end record)", size - pos);
            return Ok(Ending::Cut { at: pos, what });
        }
        let mut head = [0u8; 9];
        r.read_exact(&mut head).map_err(|e| err(format!("byte offset {pos}: {e}")))?;
        let opcode = head[0];
        let len = u64::from_le_bytes([head[1], head[2], head[3], head[4], head[5], head[6], head[7], head[8]]);
        let at = pos;
        pos += 9;
        if len > size - pos {
            let what = format!("record 0x{opcode:02x} announces {len} bytes, the file has {} left", size - pos);
            return Ok(Ending::Cut { at, what });
        }
        let here = |what: String| err(format!("record 0x{opcode:02x} at byte offset {at}: {what}"));
        match opcode {
            op::CHANNEL | op::MESSAGE | op::CHUNK => {
                body.clear();
                (&mut r).take(len).read_to_end(&mut body).map_err(|e| here(e.to_string()))?;
                if body.len() as u64 != len {
                    return Err(here(format!("{} bytes read of {len}", body.len())));
                }
                pos += len;
                let flow = if opcode == op::CHUNK {
                    let records = chunk_records(&body).map_err(here)?;
                    inner_records(&records, &mut channels, at, &mut on).map_err(here)?
                } else {
                    record(opcode, &body, &mut channels, at, &mut on).map_err(here)?
                };
                if flow.is_break() {
                    return Ok(Ending::Complete);
                }
            }
            op::DATA_END | op::FOOTER => return Ok(Ending::Complete),
            _ => {
                r.seek(SeekFrom::Current(len as i64)).map_err(|e| here(e.to_string()))?;
                pos += len;
            }
        }
    }
}

/// A chunk's records: decompressed (growing with the decoder's output, up
/// to the declared size) and checked against its CRC.
fn chunk_records(body: &[u8]) -> Result<Vec<u8>, String> {
    let mut b = Body { b: body, pos: 0 };
    let _start = b.u64("message start time")?;
    let _end = b.u64("message end time")?;
    let size = b.u64("uncompressed size")?;
    let crc = b.u32("uncompressed CRC")?;
    let compression = b.string("compression")?;
    let n = b.u64("records length")?;
    let data = b.take(n, "chunk records")?;
    if size > MAX_CHUNK_BYTES {
        return Err(format!("chunk of {size} bytes uncompressed, over the {MAX_CHUNK_BYTES}-byte limit"));
    }
    let records = match compression.as_str() {
        "" => data.to_vec(),
        "zstd" | "lz4" => {
            let mut out = Vec::new();
            let read = match compression.as_str() {
                "zstd" => {
                    zstd::stream::read::Decoder::with_buffer(data).and_then(|d| d.take(size + 1).read_to_end(&mut out))
                }
                _ => lz4::Decoder::new(data).and_then(|d| d.take(size + 1).read_to_end(&mut out)),
            };
            read.map_err(|e| format!("{compression} chunk does not decompress: {e}"))?;
            out
        }
        other => return Err(format!("chunk compression `{other}` (zstd, lz4 or none are read)")),
    };
    if records.len() as u64 != size {
        return Err(format!("chunk decompresses to {} bytes, its header says {size}", records.len()));
    }
    if crc != 0 && crc32fast::hash(&records) != crc {
        return Err(format!(
            "chunk CRC mismatch: the records' CRC is {:08x}, the chunk says {crc:08x} (the file is corrupt)",
            crc32fast::hash(&records)
        ));
    }
    Ok(records)
}

/// The records inside a chunk.
fn inner_records(
    records: &[u8],
    channels: &mut BTreeMap<u16, Channel>,
    at: u64,
    on: &mut impl FnMut(&Message<'_>) -> Result<ControlFlow<()>, String>,
) -> Result<ControlFlow<()>, String> {
    let mut b = Body { b: records, pos: 0 };
    while b.pos < records.len() {
        let inner_at = b.pos;
        let opcode = b.take(1, "record opcode")?[0];
        let len = b.u64("record length")?;
        let body = b.take(len, "record").map_err(|e| format!("chunk byte {inner_at}: {e}"))?;
        let flow = record(opcode, body, channels, at, on).map_err(|e| format!("chunk byte {inner_at}: {e}"))?;
        if flow.is_break() {
            return Ok(flow);
        }
    }
    Ok(ControlFlow::Continue(()))
}

/// A channel or message record (others are ignored).
fn record(
    opcode: u8,
    body: &[u8],
    channels: &mut BTreeMap<u16, Channel>,
    at: u64,
    on: &mut impl FnMut(&Message<'_>) -> Result<ControlFlow<()>, String>,
) -> Result<ControlFlow<()>, String> {
    let mut b = Body { b: body, pos: 0 };
    match opcode {
        op::CHANNEL => {
            let id = b.u16("channel id")?;
            let _schema = b.u16("schema id")?;
            let topic = b.string("topic")?;
            let message_encoding = b.string("message encoding")?;
            channels.insert(id, Channel { topic, message_encoding });
            Ok(ControlFlow::Continue(()))
        }
        op::MESSAGE => {
            let id = b.u16("channel id")?;
            let _sequence = b.u32("sequence")?;
            let log_time = b.u64("log time")?;
            let _publish = b.u64("publish time")?;
            let channel =
                channels.get(&id).ok_or_else(|| format!("a message on channel {id}, which no record defined"))?;
            on(&Message { channel, log_time, data: b.rest(), offset: at })
        }
        _ => Ok(ControlFlow::Continue(())),
    }
}
