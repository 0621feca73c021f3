//! Damaged recordings (issue 33): each kind of damage gives what the file still holds and
//! a report that says precisely what was lost, never an abort or a panic. Runs under the
//! bounded allocator of `tests/common/fuzz.rs`, so a size a file lies about cannot be
//! allocated unnoticed. Also: replay's exit code when nothing usable came out, and topic
//! mappings of the wrong type.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] fns panic on bad data by design

#[path = "common/fuzz.rs"]
mod fuzz;

#[global_allocator]
static A: fuzz::LimitAlloc = fuzz::LimitAlloc;

use std::collections::BTreeMap;
use std::path::Path;
use vinebench::recording::reader::{McapSummary, scan};
use vinebench::replay::{ReplayError, ReplayOptions, ReplayOutcome, replay};

/// A message as compared here: topic, sequence, publish time, payload.
type Key = (String, u32, i64, Vec<u8>);

fn corpus_file(name: &str) -> Vec<u8> {
    let p = fuzz::corpus_dir("mcap").join(name);
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// Top-level records: (offset, opcode, body length).
fn records(b: &[u8]) -> Vec<(usize, u8, usize)> {
    let mut out = Vec::new();
    let mut pos = 8;
    while pos + 9 <= b.len() {
        let len = u64::from_le_bytes(b[pos + 1..pos + 9].try_into().unwrap()) as usize;
        out.push((pos, b[pos], len));
        pos += 9 + len;
    }
    out
}

fn chunks(b: &[u8]) -> Vec<(usize, usize)> {
    records(b)
        .into_iter()
        .filter(|r| r.1 == 0x06)
        .map(|r| (r.0, r.2))
        .collect()
}

fn read(b: &[u8]) -> (Vec<Key>, McapSummary) {
    let mut got = Vec::new();
    let s = scan(b, |ch, m| {
        assert!(m.verified, "{} #{} unverified", ch.topic, m.sequence);
        got.push((
            ch.topic.clone(),
            m.sequence,
            m.publish_time.0,
            m.data.to_vec(),
        ))
    })
    .unwrap();
    (got, s)
}

/// `b` without the chunk at `at` and the message indexes that follow it.
fn without_chunk(b: &[u8], at: usize) -> Vec<u8> {
    let recs = records(b);
    let i = recs.iter().position(|r| r.0 == at).unwrap();
    let mut end = at + 9 + recs[i].2;
    for r in &recs[i + 1..] {
        if r.1 != 0x07 {
            break;
        }
        end = r.0 + 9 + r.2;
    }
    [&b[..at], &b[end..]].concat()
}

fn replay_bytes(dir: &Path, name: &str, b: &[u8]) -> Result<ReplayOutcome, ReplayError> {
    let file = dir.join(name);
    std::fs::write(&file, b).unwrap();
    replay(
        &file,
        &ReplayOptions {
            out_dir: Some(dir.join(format!("{name}.out"))),
            ..ReplayOptions::default()
        },
    )
}

/// The estimate files of a replay, by name.
fn estimates(o: &ReplayOutcome) -> BTreeMap<String, String> {
    o.report
        .sources
        .iter()
        .map(|s| {
            let p = o.dir.join(format!("estimate_{}.tum", s.name));
            (s.name.clone(), std::fs::read_to_string(p).unwrap())
        })
        .collect()
}

#[test]
fn intact_seeds_are_undamaged_and_verified() {
    for name in ["seed-zstd.mcap", "seed-uncompressed.mcap", "seed-lz4.mcap"] {
        let (got, s) = read(&corpus_file(name));
        assert!(s.damage.is_none(), "{name}: {:?}", s.damage);
        assert_eq!(s.unverified_messages, 0, "{name}");
        assert!(
            got.len() > 100 && s.chunks >= 3,
            "{name}: {} chunks",
            s.chunks
        );
        assert!(s.metadata.contains_key("vinebench.scenario"), "{name}");
        assert_eq!(s.metadata_index.len(), s.metadata.len(), "{name}");
    }
}

#[test]
fn a_file_cut_by_ten_percent_says_where_it_was_cut() {
    let tmp = tempfile::tempdir().unwrap();
    let intact = corpus_file("seed-zstd.mcap");
    let (all, _) = read(&intact);
    let cut = intact.len() * 9 / 10;
    let (got, s) = read(&intact[..cut]);
    let d = s.damage.expect("damage");
    assert!(
        d.summary_missing && d.end_magic_missing && d.bytes_unread > 0,
        "{d}"
    );
    assert_eq!(got[..], all[..got.len()], "a prefix of the intact messages");
    let text = d.to_string();
    assert!(
        text.contains("cut short") && text.contains(&format!("byte {cut}")),
        "{text}"
    );
    // Replay replays what is left and says what was lost.
    let o = replay_bytes(tmp.path(), "cut.mcap", &intact[..cut]).unwrap();
    let damage = o.report.damage.clone().expect("reported");
    assert!(damage.contains("cut short"), "{damage}");
    assert!(o.report.sources.iter().all(|s| s.poses > 0));

    // Cut inside the first chunk: nothing to replay, and the error says why (the cut),
    // not only what is missing.
    let (first, _) = chunks(&intact)[0];
    let e = replay_bytes(tmp.path(), "early.mcap", &intact[..first + 200])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("early.mcap")
            && e.contains("damaged")
            && e.contains(&format!("chunk at byte {first}")),
        "{e}"
    );
}

#[test]
fn a_damaged_header_is_named_and_the_rest_replays() {
    let tmp = tempfile::tempdir().unwrap();
    let intact = corpus_file("seed-zstd.mcap");
    let (all, _) = read(&intact);
    // The header record's length field lies: the rest of the file is found again.
    let mut b = intact.clone();
    b[9..17].copy_from_slice(&u64::MAX.to_le_bytes());
    let (got, s) = read(&b);
    let d = s.damage.expect("damage");
    assert!(d.header_damaged, "{d}");
    assert!(
        d.to_string().contains("header") && d.to_string().contains("byte 8"),
        "{d}"
    );
    assert_eq!(got, all, "every message recovered");
    let o = replay_bytes(tmp.path(), "header.mcap", &b).unwrap();
    assert!(
        o.report
            .damage
            .as_ref()
            .is_some_and(|d| d.contains("header"))
    );
    // Its profile string's length lies.
    let mut b = intact.clone();
    b[17..21].copy_from_slice(&u32::MAX.to_le_bytes());
    let (got, s) = read(&b);
    assert!(s.damage.is_some_and(|d| d.header_damaged));
    assert_eq!(got, all);

    // The scenario metadata damaged: replay says so, not "not a vinebench recording".
    let (m, _, _) = *records(&intact).iter().find(|r| r.1 == 0x0c).unwrap();
    let mut b = intact.clone();
    b[m + 9..m + 13].copy_from_slice(&u32::MAX.to_le_bytes());
    let (_, s) = read(&b);
    assert_eq!(s.damage.unwrap().damaged_metadata, [m as u64]);
    let e = replay_bytes(tmp.path(), "meta.mcap", &b)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("meta.mcap")
            && e.contains("vinebench recording whose scenario metadata")
            && e.contains(&format!("metadata record at byte {m}"))
            && !e.contains("not a vinebench recording"),
        "{e}"
    );
    // Header and metadata both: the summary's metadata index names what was lost.
    b[9..17].copy_from_slice(&u64::MAX.to_le_bytes());
    let e = replay_bytes(tmp.path(), "both.mcap", &b)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("vinebench recording whose scenario metadata")
            && e.contains(&format!("vinebench.scenario (byte {m})"))
            && e.contains("header"),
        "{e}"
    );
}

#[test]
fn a_chunk_failing_its_crc_is_dropped_whole() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, flip_data) in [("seed-zstd.mcap", false), ("seed-uncompressed.mcap", true)] {
        let intact = corpus_file(name);
        let cs = chunks(&intact);
        let (at, len) = cs[cs.len() / 2];
        let crc_at = at + 9 + 24;
        let mut b = intact.clone();
        if flip_data {
            // A byte of a message's payload, not its framing: only the CRC sees it.
            b[at + 9 + len - 20] ^= 0x01;
        } else {
            b[crc_at] ^= 0x01;
        }
        let removed = without_chunk(&intact, at);
        let (got, s) = read(&b);
        let (want, _) = read(&removed);
        let (all, _) = read(&intact);
        assert_eq!(got, want, "{name}: as if the chunk were not there");
        assert!(got.len() < all.len(), "{name}");
        let d = s.damage.expect("damage");
        assert_eq!(d.chunks_lost, 1, "{name}: {d}");
        let lost = &d.lost_chunks[0];
        assert_eq!(lost.offset, at as u64);
        assert!(lost.reason.contains("CRC mismatch"), "{}", lost.reason);
        assert_eq!(
            lost.message_count(),
            Some((all.len() - got.len()) as u64),
            "{name}: {lost}"
        );
        assert_eq!(d.messages_lost, Some((all.len() - got.len()) as u64));
        let text = d.to_string();
        assert!(
            text.contains(&format!("chunk at byte {at}")) && text.contains("message(s)"),
            "{text}"
        );
        // Replay: the outputs of the file without that chunk, not the intact file's.
        let o_damaged = replay_bytes(tmp.path(), &format!("crc-{name}"), &b).unwrap();
        let o_removed = replay_bytes(tmp.path(), &format!("removed-{name}"), &removed).unwrap();
        let o_intact = replay_bytes(tmp.path(), &format!("intact-{name}"), &intact).unwrap();
        assert_eq!(estimates(&o_damaged), estimates(&o_removed), "{name}");
        assert_ne!(estimates(&o_damaged), estimates(&o_intact), "{name}");
        let damage = o_damaged.report.damage.unwrap();
        assert!(damage.contains("CRC mismatch"), "{damage}");
    }
}

#[test]
fn a_missing_end_magic_is_reported() {
    let intact = corpus_file("seed-zstd.mcap");
    let (all, _) = read(&intact);
    for b in [intact[..intact.len() - 8].to_vec(), {
        let mut b = intact.clone();
        let n = b.len();
        b[n - 8..].fill(0);
        b
    }] {
        let (got, s) = read(&b);
        assert_eq!(got, all);
        let d = s.damage.expect("damage");
        assert!(d.end_magic_missing && !d.summary_missing, "{d}");
        assert!(d.to_string().contains("end magic"), "{d}");
        assert_eq!(d.chunks_lost, 0);
    }
}

#[test]
fn a_bad_data_section_crc_is_reported() {
    let intact = corpus_file("seed-zstd.mcap");
    let (all, _) = read(&intact);
    let recs = records(&intact);
    let (de, _, _) = *recs.iter().find(|r| r.1 == 0x0f).unwrap();
    let (m, _, mlen) = *recs.iter().find(|r| r.1 == 0x0c).unwrap();
    // The stored CRC altered; a byte of the recorded scenario's text altered (no other
    // CRC covers the metadata).
    for at in [de + 9, m + 9 + mlen - 3] {
        let mut b = intact.clone();
        b[at] ^= 0x02;
        let (got, s) = read(&b);
        assert_eq!(got, all);
        let d = s.damage.expect("damage");
        assert!(d.data_crc_mismatch, "{d}");
        let text = d.to_string();
        assert!(
            text.contains("data-section CRC mismatch") && text.contains(&format!("byte {de}")),
            "{text}"
        );
    }
}

#[test]
fn chunk_size_lies_are_refused_before_allocating() {
    let intact = corpus_file("seed-zstd.mcap");
    let (all, _) = read(&intact);
    let cs = chunks(&intact);
    let (at, _) = cs[cs.len() / 2];
    let usize_at = at + 9 + 16;
    let size = u64::from_le_bytes(intact[usize_at..usize_at + 8].try_into().unwrap());
    // The 9 crashes of issue 33 were flips of this field (aborts allocating up to 2.8e18
    // bytes, "capacity overflow"); and the lies just around the truth.
    for lie in [
        size ^ (0x27 << 56),
        size ^ (0x80 << 56),
        size ^ (0x04 << 40),
        size ^ (0x10 << 24),
        u64::MAX,
        size + 1,
        size - 1,
        0,
    ] {
        let mut b = intact.clone();
        b[usize_at..usize_at + 8].copy_from_slice(&lie.to_le_bytes());
        let (got, s) = read(&b);
        let d = s.damage.expect("damage");
        assert_eq!(d.chunks_lost, 1, "{lie}: {d}");
        let reason = &d.lost_chunks[0].reason;
        assert!(
            reason.contains(&lie.to_string()) || reason.contains("decompress"),
            "{lie}: {reason}"
        );
        assert!(got.len() < all.len() && got.iter().all(|m| all.contains(m)));
    }
}

#[test]
fn a_lying_record_length_costs_at_most_one_record() {
    let intact = corpus_file("seed-zstd.mcap");
    let (all, _) = read(&intact);
    let cs = chunks(&intact);
    let (at, len) = cs[cs.len() / 2];
    for lie in [u64::MAX, len as u64 + 1, len as u64 - 1, 1 << 40] {
        let mut b = intact.clone();
        b[at + 1..at + 9].copy_from_slice(&lie.to_le_bytes());
        let (got, s) = read(&b);
        // The chunk's own header gives its length: nothing is lost.
        assert_eq!(got, all, "{lie}");
        let d = s.damage.expect("damage");
        assert!(d.to_string().contains("length field"), "{d}");
    }
    // The chunk header's compressed size lies: the record's length holds.
    let csize_at = {
        let comp_len =
            u32::from_le_bytes(intact[at + 9 + 28..at + 9 + 32].try_into().unwrap()) as usize;
        at + 9 + 32 + comp_len
    };
    let csize = u64::from_le_bytes(intact[csize_at..csize_at + 8].try_into().unwrap());
    for lie in [csize + 1, csize - 1, u64::MAX, 0] {
        let mut b = intact.clone();
        b[csize_at..csize_at + 8].copy_from_slice(&lie.to_le_bytes());
        let (got, s) = read(&b);
        assert_eq!(got, all, "{lie}");
        let d = s.damage.expect("damage");
        assert!(d.to_string().contains("compressed_size says"), "{d}");
    }
    // A metadata record's length lies: reading resumes at the next chunk.
    let (m, _, mlen) = *records(&intact).iter().find(|r| r.1 == 0x0c).unwrap();
    let mut b = intact.clone();
    b[m + 1..m + 9].copy_from_slice(&(mlen as u64 + 3).to_le_bytes());
    let (got, s) = read(&b);
    let d = s.damage.expect("damage");
    assert!(
        d.bytes_skipped > 0 && d.to_string().contains("reading resumed"),
        "{d}"
    );
    assert!(
        got.len() + 200 > all.len(),
        "{} of {}",
        got.len(),
        all.len()
    );
}

#[test]
fn replay_with_no_pose_exits_2() {
    let tmp = tempfile::tempdir().unwrap();
    let rec = fuzz::corpus_dir("mcap").join("seed-zstd.mcap");
    let map = fuzz::corpus_dir("topic-mapping").join("no-poses.toml");
    let out = assert_cmd::Command::cargo_bin("vinebench")
        .unwrap()
        .args([
            "replay",
            rec.to_str().unwrap(),
            "--config",
            map.to_str().unwrap(),
        ])
        .arg("--out")
        .arg(tmp.path().join("out"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(2), "{stdout}\n{stderr}");
    assert!(
        stderr.contains("no estimate source produced a pose") && stderr.contains("gnss 0 poses"),
        "{stderr}"
    );
    assert!(!stdout.contains("PASS"), "{stdout}");
    // The report says it too.
    let json = std::fs::read_to_string(tmp.path().join("out/report.json")).unwrap();
    assert!(json.contains("\"nothing_usable\": \""), "{json}");
}

#[test]
fn a_mapping_to_a_topic_of_the_wrong_type_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let rec = fuzz::corpus_dir("mcap").join("seed-zstd.mcap");
    for (topic, ty) in [
        ("/tf_static", "tf2_msgs/TFMessage"),
        ("/tf", "tf2_msgs/TFMessage"),
        ("/imu/data", "sensor_msgs/Imu"),
    ] {
        let map = tmp.path().join("topics.toml");
        std::fs::write(
            &map,
            format!("[topics]\ngnss_fix = \"/gnss/fix\"\ntracking_odom = \"{topic}\"\n"),
        )
        .unwrap();
        let e = replay(
            &rec,
            &ReplayOptions {
                config: Some(map.clone()),
                out_dir: Some(tmp.path().join("out")),
                ..ReplayOptions::default()
            },
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with(&*map.to_string_lossy())
                && e.contains("`topics.tracking_odom`")
                && e.contains(topic)
                && e.contains(ty)
                && e.contains("nav_msgs/Odometry"),
            "{e}"
        );
    }
    // One topic for two inputs.
    let map = tmp.path().join("twice.toml");
    std::fs::write(
        &map,
        "[topics]\nimu = \"/imu/data\"\nwheel_odom = \"/imu/data\"\n",
    )
    .unwrap();
    let e = replay(
        &rec,
        &ReplayOptions {
            config: Some(map.clone()),
            out_dir: Some(tmp.path().join("out2")),
            ..ReplayOptions::default()
        },
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("twice.toml") && e.contains("both name"), "{e}");
}

#[test]
fn the_report_of_a_file_of_many_broken_chunks_stays_bounded() {
    use vinebench::recording::reader::{MAGIC, MAX_REPORTED};
    let mut b = MAGIC.to_vec();
    let header = [&4u32.to_le_bytes()[..], b"ros2", &0u32.to_le_bytes()].concat();
    b.push(0x01);
    b.extend((header.len() as u64).to_le_bytes());
    b.extend(&header);
    let n = 10_000u64;
    for _ in 0..n {
        // A chunk of one uncompressed byte whose CRC does not match.
        let body = [
            &0u64.to_le_bytes()[..],
            &0u64.to_le_bytes(),
            &1u64.to_le_bytes(),
            &1u32.to_le_bytes(),
            &0u32.to_le_bytes(),
            &1u64.to_le_bytes(),
            &[0u8],
        ]
        .concat();
        b.push(0x06);
        b.extend((body.len() as u64).to_le_bytes());
        b.extend(&body);
    }
    let (got, s) = read(&b);
    assert!(got.is_empty());
    let d = s.damage.expect("damage");
    assert_eq!(d.chunks_lost, n);
    assert_eq!(d.lost_chunks.len(), MAX_REPORTED);
    let text = d.to_string();
    assert!(
        text.contains(&format!("{} more chunk(s) lost", n - MAX_REPORTED as u64)),
        "{}",
        &text[text.len().saturating_sub(300)..]
    );
    assert!(text.len() < 64 * 1024, "{} bytes of report", text.len());
}
