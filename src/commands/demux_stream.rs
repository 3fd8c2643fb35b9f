//! Streaming `demux` for large native `.npy` files: a reader thread, the rayon solve and a
//! writer thread work on consecutive bands of pixels at once, with recycled buffers, so
//! neither the input nor the output is ever held whole and file I/O overlaps the solve.
//! The output is written atomically: a failure anywhere leaves no file behind.

use anaglyph_core::demux::{demultiplex_into, DemuxOptions, DemuxReport, Sample};
use anaglyph_core::io::{npy_header, write_atomically, zeroed_large, NpyRowReader};
use std::path::Path;
use std::sync::mpsc::{channel, sync_channel, Receiver};

/// Pixels per band: 256 Ki pixels × 52 unknowns × 4 B = 54 MB per output buffer, large
/// enough to keep both cores busy, small enough that three bands in flight stay cheap.
const BAND_PIXELS: usize = 1 << 18;
/// Bands queued between stages.
const QUEUE_DEPTH: usize = 2;

/// What the writer receives: a band buffer and how many of its values to write.
enum ToWriter<T> {
    Band(Vec<T>, usize),
    Done,
}

/// Streams `reader` through the solver into the `.npy` file `out`; returns the merged report.
#[allow(clippy::too_many_arguments)]
pub fn stream<T: Sample>(
    mut reader: NpyRowReader,
    c: &[f64],
    rows: usize,
    n: usize,
    mask: Option<&[bool]>,
    options: &DemuxOptions,
    out: &Path,
    descr: &str,
) -> anyhow::Result<DemuxReport> {
    let mut out_shape = reader.shape.clone();
    if let Some(last) = out_shape.last_mut() {
        *last = n;
    }
    let header = npy_header(descr, &out_shape);
    std::thread::scope(|scope| -> anyhow::Result<DemuxReport> {
        let (band_tx, band_rx) =
            sync_channel::<anaglyph_core::Result<(Vec<T>, usize)>>(QUEUE_DEPTH);
        let (spent_input_tx, spent_input_rx) = channel::<Vec<T>>();
        let (write_tx, write_rx) = sync_channel::<ToWriter<T>>(QUEUE_DEPTH);
        let (spent_output_tx, spent_output_rx) = channel::<Vec<T>>();

        scope.spawn(move || loop {
            let mut buffer = spent_input_rx
                .try_recv()
                .unwrap_or_else(|_| zeroed_large(BAND_PIXELS * rows));
            match reader.read_rows(&mut buffer) {
                Ok(0) => return,
                Ok(pixels) => {
                    if band_tx.send(Ok((buffer, pixels))).is_err() {
                        return;
                    }
                }
                Err(e) => {
                    let _ = band_tx.send(Err(e));
                    return;
                }
            }
        });

        let writer = scope.spawn(move || write_bands(out, &header, write_rx, spent_output_tx));

        let mut report = DemuxReport::default();
        let mut offset = 0usize;
        let solved = (|| -> anyhow::Result<()> {
            for band in band_rx {
                let (input, pixels) = band?;
                let mut output = spent_output_rx
                    .try_recv()
                    .unwrap_or_else(|_| zeroed_large(BAND_PIXELS * n));
                let band_mask = mask.map(|m| &m[offset * rows..(offset + pixels) * rows]);
                let part = demultiplex_into(
                    c,
                    rows,
                    &input[..pixels * rows],
                    band_mask,
                    0..n,
                    options,
                    &mut output[..pixels * n],
                )?;
                report.pixels += part.pixels;
                report.bounded_pixels += part.bounded_pixels;
                report.unmeasured_pixels += part.unmeasured_pixels;
                report.iterations += part.iterations;
                report.distinct_masks = report.distinct_masks.max(part.distinct_masks);
                offset += pixels;
                let _ = spent_input_tx.send(input);
                if write_tx.send(ToWriter::Band(output, pixels * n)).is_err() {
                    break;
                }
            }
            Ok(())
        })();
        if solved.is_ok() {
            let _ = write_tx.send(ToWriter::Done);
        }
        drop(write_tx);
        let written = writer
            .join()
            .map_err(|_| anyhow::anyhow!("the writer thread panicked"))?;
        solved?;
        written?;
        Ok(report)
    })
}

/// Writes the header and every band; fails (and so leaves no file) unless `Done` arrives.
fn write_bands<T: Sample>(
    out: &Path,
    header: &[u8],
    bands: Receiver<ToWriter<T>>,
    spent: std::sync::mpsc::Sender<Vec<T>>,
) -> anaglyph_core::Result<()> {
    write_atomically(out, |w| {
        w.write_all(header)?;
        for message in bands {
            match message {
                ToWriter::Band(buffer, values) => {
                    w.write_all(bytemuck::cast_slice(&buffer[..values]))?;
                    let _ = spent.send(buffer);
                }
                ToWriter::Done => return Ok(()),
            }
        }
        Err(std::io::Error::other(
            "demultiplexing stopped before the last band",
        ))
    })
}
