//! Copies a recording keeping only what a replay reads: the frame records, cuts, topology edits
//! and keyframes, with the scene, its files and the session's metadata. The golden recordings
//! are kept this way (see `recordings/README.md`):
//!
//! ```sh
//! cargo run --release -p incise_replay --example slim_recording -- IN.mcap OUT.mcap
//! ```

use anyhow::Context;
use incise_record::{CUT_TOPIC, EDIT_TOPIC, FRAME_TOPIC, KEYFRAME_TOPIC};
use std::io::BufWriter;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let (Some(input), Some(output)) = (args.next(), args.next()) else {
        anyhow::bail!("usage: slim_recording IN.mcap OUT.mcap");
    };
    let bytes = std::fs::read(&input).with_context(|| format!("cannot read {input}"))?;
    let file = std::fs::File::create(&output).with_context(|| format!("cannot create {output}"))?;
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Lz4))
        .profile("")
        .create(BufWriter::new(file))?;
    // Metadata and attachments sit outside the chunks.
    for record in mcap::read::LinearReader::new(&bytes)? {
        match record.with_context(|| format!("{input}: a damaged record"))? {
            mcap::records::Record::Metadata(m) => writer.write_metadata(&m)?,
            mcap::records::Record::Attachment { header, data, .. } => {
                writer.attach(&mcap::Attachment {
                    log_time: header.log_time,
                    create_time: header.create_time,
                    name: header.name,
                    media_type: header.media_type,
                    data,
                })?;
            }
            _ => {}
        }
    }
    let (mut kept, mut dropped) = (0u64, 0u64);
    for message in mcap::MessageStream::new(&bytes)? {
        let message = message.with_context(|| format!("{input}: a damaged message"))?;
        if [FRAME_TOPIC, CUT_TOPIC, EDIT_TOPIC, KEYFRAME_TOPIC].contains(&&*message.channel.topic) {
            writer.write(&message)?;
            kept += 1;
        } else {
            dropped += 1;
        }
    }
    writer.finish()?;
    println!("{output}: {kept} messages kept, {dropped} left out");
    Ok(())
}
