//! A check of a TIFF's first directory before a decoder reads it: every tag's values
//! must fit inside the file. The `tiff` crate reads the first directory with its default
//! limits (256 MiB of values) before a caller can lower them, so a few hundred bytes
//! declaring a tag of eight million values would cost 250 MB; this refuses them first.
//!
//! In: the path of a TIFF (classic or BigTIFF, either byte order). Out: nothing, or an
//! [`Error::Decode`] naming the tag, its value count and the file's size.

use crate::{Error, Result};
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

/// Bytes per value of a TIFF field type (unknown types count as one byte).
fn type_bytes(field_type: u16) -> u64 {
    match field_type {
        3 | 8 => 2,
        4 | 9 | 11 | 13 => 4,
        5 | 10 | 12 | 16 | 17 | 18 => 8,
        _ => 1,
    }
}

/// Refuses a TIFF at `path` whose first directory declares values the file cannot hold;
/// anything that is not a TIFF passes untouched (its own decoder judges it).
pub(crate) fn check_tiff_directory(path: &Path) -> Result<()> {
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let file_bytes = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut head = [0u8; 16];
    if file.read_exact(&mut head).is_err() {
        return Ok(());
    }
    let little = match &head[..2] {
        b"II" => true,
        b"MM" => false,
        _ => return Ok(()),
    };
    let u16_at = |b: &[u8]| {
        let pair = [b[0], b[1]];
        if little {
            u16::from_le_bytes(pair)
        } else {
            u16::from_be_bytes(pair)
        }
    };
    let u32_at = |b: &[u8]| {
        let quad = [b[0], b[1], b[2], b[3]];
        u64::from(if little {
            u32::from_le_bytes(quad)
        } else {
            u32::from_be_bytes(quad)
        })
    };
    let u64_at = |b: &[u8]| {
        let octet: [u8; 8] = b[..8].try_into().unwrap_or_default();
        if little {
            u64::from_le_bytes(octet)
        } else {
            u64::from_be_bytes(octet)
        }
    };
    let big = match u16_at(&head[2..4]) {
        42 => false,
        43 => true,
        _ => return Ok(()),
    };
    let directory = if big {
        u64_at(&head[8..16])
    } else {
        u32_at(&head[4..8])
    };
    let (count_bytes, entry_bytes) = if big { (8, 20) } else { (2, 12) };
    if directory.saturating_add(count_bytes) > file_bytes {
        return Ok(()); // the decoder reports a directory outside the file
    }
    file.seek(SeekFrom::Start(directory))
        .map_err(|e| Error::io(path, e))?;
    let mut count = [0u8; 8];
    file.read_exact(&mut count[..count_bytes as usize])
        .map_err(|e| Error::io(path, e))?;
    let entries = if big {
        u64_at(&count)
    } else {
        u64::from(u16_at(&count))
    };
    let table = entries.saturating_mul(entry_bytes);
    if directory.saturating_add(count_bytes).saturating_add(table) > file_bytes {
        return Err(Error::decode(
            path,
            format!("its first directory declares {entries} tags, more than its {file_bytes} bytes hold"),
        ));
    }
    let mut entry = vec![0u8; entry_bytes as usize];
    for _ in 0..entries {
        file.read_exact(&mut entry)
            .map_err(|e| Error::io(path, e))?;
        let tag = u16_at(&entry[0..2]);
        let values = if big {
            u64_at(&entry[4..12])
        } else {
            u32_at(&entry[4..8])
        };
        let bytes = values.saturating_mul(type_bytes(u16_at(&entry[2..4])));
        if bytes > file_bytes {
            return Err(Error::decode(
                path,
                format!(
                    "tag {tag} declares {values} values ({bytes} bytes) but the file holds \
                     {file_bytes} bytes (a truncated or corrupt TIFF?)"
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A little-endian TIFF whose one tag (StripByteCounts, LONG) declares `values`.
    fn tiff_with_tag_count(values: u32) -> Vec<u8> {
        let mut bytes = b"II\x2a\x00\x08\x00\x00\x00".to_vec();
        bytes.extend_from_slice(&1u16.to_le_bytes());
        bytes.extend_from_slice(&279u16.to_le_bytes());
        bytes.extend_from_slice(&4u16.to_le_bytes());
        bytes.extend_from_slice(&values.to_le_bytes());
        bytes.extend_from_slice(&0u32.to_le_bytes());
        bytes.extend_from_slice(&[0u8; 4]);
        bytes
    }

    #[test]
    fn a_tag_larger_than_its_file_is_refused_and_a_plausible_one_passes() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.tif");
        std::fs::write(&path, tiff_with_tag_count(8_060_929)).unwrap();
        let refused = check_tiff_directory(&path);
        let message = refused
            .as_ref()
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert_eq!(refused.err().map(|e| e.kind()), Some("Decode"));
        assert!(
            message.contains("tag 279 declares 8060929 values"),
            "{message}"
        );
        std::fs::write(&path, tiff_with_tag_count(1)).unwrap();
        check_tiff_directory(&path).unwrap();
        std::fs::write(&path, b"\x89PNG not a tiff").unwrap();
        check_tiff_directory(&path).unwrap();
    }
}
