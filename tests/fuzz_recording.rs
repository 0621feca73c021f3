//! Fuzz targets of the recording reader, replay and the topic-mapping parser (issue 33):
//! structure-aware mutations (byte flips, truncations, length-field lies, ...) of the real
//! files in `tests/fuzz/corpus/{mcap,topic-mapping}/`, under the bounded allocator of
//! `tests/common/fuzz.rs`. The property: no panic, no abort, no allocation over the bound,
//! a named error or a recovered result; and for the reader, every CRC-verified message a
//! damaged file delivers is byte for byte one of the intact file's messages.
//!
//! `VINEBENCH_FUZZ_CASES` sets the mutated inputs per target (default 64). The corpus holds
//! the seeds (zstd, uncompressed and lz4 chunks) and every reproducer found; regenerate the
//! reproducers with `cargo test --release --test fuzz_recording -- --ignored
//! write_reproducers` after changing the seeds.

#[path = "common/fuzz.rs"]
mod fuzz;

#[global_allocator]
static A: fuzz::LimitAlloc = fuzz::LimitAlloc;

use proptest::prelude::*;
use std::collections::{BTreeMap, HashSet};
use std::path::Path;
use std::sync::OnceLock;
use vinebench::recording::reader::{self, ChannelInfo, RawMessage, scan};
use vinebench::replay::{ReplayConfig, ReplayOptions, replay};

/// A message as the property compares it: topic, sequence, times, payload.
type Key = (String, u32, i64, i64, Vec<u8>);

fn key(ch: &ChannelInfo, m: &RawMessage<'_>) -> Key {
    (
        ch.topic.clone(),
        m.sequence,
        m.log_time.0,
        m.publish_time.0,
        m.data.to_vec(),
    )
}

/// The seeds of the reader and replay targets with their intact messages.
struct Seed {
    name: String,
    bytes: Vec<u8>,
    messages: HashSet<Key>,
}

fn seeds() -> &'static [Seed] {
    static SEEDS: OnceLock<Vec<Seed>> = OnceLock::new();
    SEEDS.get_or_init(|| {
        fuzz::corpus("mcap")
            .into_iter()
            .filter(|(p, _)| {
                let n = file_name(p);
                n.starts_with("seed-") && !n.contains("--")
            })
            .map(|(p, bytes)| {
                let mut messages = HashSet::new();
                let s = scan(&bytes, |ch, m| {
                    messages.insert(key(ch, m));
                })
                .unwrap_or_else(|e| panic!("{}: {e}", p.display()));
                assert!(s.damage.is_none(), "{}: {:?}", p.display(), s.damage);
                assert!(!messages.is_empty(), "{}: no messages", p.display());
                Seed {
                    name: file_name(&p),
                    bytes,
                    messages,
                }
            })
            .collect()
    })
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default()
}

/// The reader's property on `bytes`, a damaged `seed` (`None`: no intact twin known).
fn check_scan(what: &str, bytes: &[u8], seed: Option<&Seed>) {
    let (r, got) = fuzz::no_panic(what, || {
        let mut got = Vec::new();
        let r = scan(bytes, |ch, m| got.push((key(ch, m), m.verified)));
        (r, got)
    });
    match r {
        Ok(s) => {
            assert_eq!(s.messages as usize, got.len(), "{what}: message count");
            let unverified = got.iter().filter(|(_, v)| !v).count() as u64;
            assert_eq!(s.unverified_messages, unverified, "{what}");
            if let Some(seed) = seed {
                for (k, verified) in &got {
                    if *verified {
                        assert!(
                            seed.messages.contains(k),
                            "{what}: a verified message the intact {} does not hold: {} #{}",
                            seed.name,
                            k.0,
                            k.1
                        );
                    }
                }
                if got.len() < seed.messages.len() || unverified > 0 {
                    assert!(
                        s.damage.is_some(),
                        "{what}: messages lost or unverified without a damage report"
                    );
                }
            }
            if let Some(d) = &s.damage {
                assert!(!d.to_string().is_empty(), "{what}: empty damage report");
            }
        }
        Err(e) => {
            let e = e.to_string();
            assert!(e.contains("MCAP") || e.contains("expected"), "{what}: {e}");
        }
    }
}

/// Replay's property on a recording: a report whose outputs are all there, or an error
/// that names the file.
fn check_replay(what: &str, bytes: &[u8], config: Option<&Path>) {
    let tmp = tempfile::tempdir().expect("a temporary folder");
    let file = tmp.path().join("fuzzed.mcap");
    std::fs::write(&file, bytes).expect("writing the fuzzed recording");
    let out = tmp.path().join("out");
    let r = fuzz::no_panic(what, || {
        replay(
            &file,
            &ReplayOptions {
                config: config.map(Path::to_path_buf),
                out_dir: Some(out.clone()),
                runs_root: tmp.path().to_path_buf(),
                replace: false,
            },
        )
    });
    match r {
        Ok(o) => {
            let json = std::fs::read_to_string(o.dir.join("report.json"))
                .unwrap_or_else(|e| panic!("{what}: report.json: {e}"));
            serde_json::from_str::<serde_json::Value>(&json)
                .unwrap_or_else(|e| panic!("{what}: report.json does not parse: {e}"));
            assert!(o.dir.join("report.md").is_file(), "{what}: no report.md");
            for s in &o.report.sources {
                let p = o.dir.join(format!("estimate_{}.tum", s.name));
                let text = std::fs::read_to_string(&p)
                    .unwrap_or_else(|e| panic!("{what}: {}: {e}", p.display()));
                assert_eq!(
                    text.lines().filter(|l| !l.starts_with('#')).count(),
                    s.poses,
                    "{what}: {}",
                    p.display()
                );
            }
        }
        Err(e) => {
            let e = e.to_string();
            let named = e.contains("fuzzed.mcap")
                || config.is_some_and(|c| e.contains(&*c.to_string_lossy()));
            assert!(named, "{what}: the error does not name the file: {e}");
        }
    }
}

#[test]
fn the_mcap_corpus_reads_and_replays() {
    let seeds = seeds();
    let mut n = 0;
    for (p, bytes) in fuzz::corpus("mcap") {
        let name = file_name(&p);
        // A reproducer `<seed stem>--<what>.mcap` is compared with its seed.
        let seed = seeds
            .iter()
            .find(|s| name.split("--").next() == s.name.strip_suffix(".mcap"));
        check_scan(&name, &bytes, seed);
        check_replay(&name, &bytes, None);
        n += 1;
    }
    assert!(n >= 20, "{n} corpus files");
}

#[test]
fn the_seeds_replay_to_poses() {
    for s in seeds() {
        let tmp = tempfile::tempdir().expect("a temporary folder");
        let file = tmp.path().join(&s.name);
        std::fs::write(&file, &s.bytes).expect("write");
        let o = replay(
            &file,
            &ReplayOptions {
                out_dir: Some(tmp.path().join("out")),
                ..ReplayOptions::default()
            },
        )
        .unwrap_or_else(|e| panic!("{}: {e}", s.name));
        assert!(o.report.damage.is_none(), "{}", s.name);
        assert!(o.report.nothing_usable.is_none(), "{}", s.name);
        assert!(o.report.sources.iter().all(|x| x.poses > 0), "{}", s.name);
    }
}

fn seed_index() -> impl Strategy<Value = usize> {
    0..seeds().len()
}

proptest! {
    #![proptest_config(fuzz::config())]

    /// Mutated recordings: the reader recovers, verified messages are the intact ones.
    #[test]
    fn fuzz_reader(i in seed_index(), muts in fuzz::mutations(4)) {
        let seed = &seeds()[i];
        let bytes = fuzz::mutate(&seed.bytes, &muts);
        check_scan(&format!("{} with {muts:?}", seed.name), &bytes, Some(seed));
    }

    /// Mutated recordings, end to end through replay.
    #[test]
    fn fuzz_replay(i in seed_index(), muts in fuzz::mutations(3)) {
        let seed = &seeds()[i];
        let bytes = fuzz::mutate(&seed.bytes, &muts);
        check_replay(&format!("{} with {muts:?}", seed.name), &bytes, None);
    }

    /// Mutated topic-mapping files: parsed, and when they parse, used on a seed.
    #[test]
    fn fuzz_topic_mapping(i in 0..mappings().len(), muts in fuzz::mutations(3)) {
        let (name, text) = &mappings()[i];
        let bytes = fuzz::mutate(text, &muts);
        check_mapping(&format!("{name} with {muts:?}"), &bytes);
    }
}

fn mappings() -> &'static [(String, Vec<u8>)] {
    static M: OnceLock<Vec<(String, Vec<u8>)>> = OnceLock::new();
    M.get_or_init(|| {
        fuzz::corpus("topic-mapping")
            .into_iter()
            .map(|(p, b)| (file_name(&p), b))
            .collect()
    })
}

/// The mapping parser's property: a configuration or an error naming the file; a
/// configuration that parses replays the zstd seed to a report or a named error.
fn check_mapping(what: &str, bytes: &[u8]) {
    let tmp = tempfile::tempdir().expect("a temporary folder");
    let file = tmp.path().join("mapping.toml");
    std::fs::write(&file, bytes).expect("write");
    let parsed = fuzz::no_panic(what, || ReplayConfig::load(&file));
    match parsed {
        Ok(_) => {
            let seed = &seeds()[0];
            check_replay(what, &seed.bytes, Some(&file));
        }
        Err(e) => {
            let e = e.to_string();
            assert!(e.contains("mapping.toml"), "{what}: {e}");
        }
    }
}

#[test]
fn the_topic_mapping_corpus_parses_or_names_its_error() {
    for (name, bytes) in mappings() {
        check_mapping(name, bytes);
    }
}

// ---- the reproducers -------------------------------------------------------------------

/// Top-level records of an MCAP file: (offset, opcode, body length).
fn records(b: &[u8]) -> Vec<(usize, u8, usize)> {
    let mut out = Vec::new();
    let mut pos = 8;
    while pos + 9 <= b.len() {
        let len = u64::from_le_bytes(b[pos + 1..pos + 9].try_into().expect("8 bytes")) as usize;
        out.push((pos, b[pos], len));
        pos += 9 + len;
    }
    out
}

fn put_u64(b: &mut [u8], at: usize, v: u64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

fn put_u32(b: &mut [u8], at: usize, v: u32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

/// The lz4 seed: the zstd seed's messages and metadata written again with lz4 chunks.
fn lz4_seed(zstd_seed: &[u8]) -> Vec<u8> {
    let mut meta = BTreeMap::new();
    let s = scan(zstd_seed, |_, _| {}).expect("the zstd seed reads");
    for (k, v) in &s.metadata {
        meta.insert(k.clone(), v.clone());
    }
    let mut file = std::io::Cursor::new(Vec::new());
    let mut w = mcap::WriteOptions::new()
        .profile(&s.profile)
        .library(&s.library)
        .chunk_size(Some(50 * 1024))
        .compression(Some(mcap::Compression::Lz4))
        .create(&mut file)
        .expect("an lz4 writer");
    let mut first = true;
    for m in mcap::MessageStream::new(zstd_seed).expect("the zstd seed streams") {
        let m = m.expect("an intact message");
        w.write(&m).expect("write");
        if first {
            // The scenario where vinebench writes it: after the first messages.
            for (name, entries) in &meta {
                w.write_metadata(&mcap::records::Metadata {
                    name: name.clone(),
                    metadata: entries.clone(),
                })
                .expect("metadata");
            }
            first = false;
        }
    }
    w.finish().expect("finish");
    drop(w);
    file.into_inner()
}

/// Every damage kind found by hand and by fuzzing, as files (`<seed>--<what>.mcap`).
#[test]
#[ignore = "regenerates tests/fuzz/corpus/mcap/ from its seeds"]
fn write_reproducers() {
    let dir = fuzz::corpus_dir("mcap");
    let zstd = std::fs::read(dir.join("seed-zstd.mcap")).expect("seed-zstd.mcap");
    let plain = std::fs::read(dir.join("seed-uncompressed.mcap")).expect("seed");
    let lz4 = lz4_seed(&zstd);
    std::fs::write(dir.join("seed-lz4.mcap"), &lz4).expect("write");
    let mut files: Vec<(String, Vec<u8>)> = Vec::new();
    for (stem, seed) in [
        ("seed-zstd", &zstd),
        ("seed-uncompressed", &plain),
        ("seed-lz4", &lz4),
    ] {
        let recs = records(seed);
        let chunks: Vec<(usize, usize)> = recs
            .iter()
            .filter(|r| r.1 == 0x06)
            .map(|r| (r.0, r.2))
            .collect();
        assert!(chunks.len() >= 3, "{stem}: {} chunks", chunks.len());
        let (mid, mid_len) = chunks[chunks.len() / 2];
        // Chunk body: start u64, end u64, uncompressed_size u64, crc u32, compression
        // string, compressed_size u64.
        let usize_at = mid + 9 + 16;
        let crc_at = usize_at + 8;
        let comp_len =
            u32::from_le_bytes(seed[crc_at + 4..crc_at + 8].try_into().expect("4")) as usize;
        let csize_at = crc_at + 8 + comp_len;
        let data_at = csize_at + 8;
        // Every kind on the zstd seed (what vinebench writes); the chunk kinds on the
        // others (the corpus stays a few MB).
        let kept: &[&str] = match stem {
            "seed-zstd" => &[],
            "seed-lz4" => &[
                "usize-flip-byte7-0x27",
                "usize-flip-byte7-0x80",
                "usize-flip-byte5-0x04",
                "usize-flip-byte3-0x10",
                "usize-max",
                "crc-flip",
                "data-flip",
                "truncated-10pct",
            ],
            _ => &[
                "usize-flip-byte7-0x27",
                "usize-plus-one",
                "crc-flip",
                "data-flip",
            ],
        };
        let mut add = |what: &str, f: &dyn Fn(&mut Vec<u8>)| {
            if !kept.is_empty() && !kept.contains(&what) {
                return;
            }
            let mut b = seed.clone();
            f(&mut b);
            files.push((format!("{stem}--{what}.mcap"), b));
        };
        // The crashes of issue 33: single-byte flips of a chunk's uncompressed size.
        add("usize-flip-byte7-0x27", &|b| b[usize_at + 7] ^= 0x27); // ~2.8e18: abort
        add("usize-flip-byte7-0x80", &|b| b[usize_at + 7] ^= 0x80); // capacity overflow
        add("usize-flip-byte5-0x04", &|b| b[usize_at + 5] ^= 0x04); // ~1e15
        add("usize-flip-byte3-0x10", &|b| b[usize_at + 3] ^= 0x10); // ~268 MB
        add("usize-max", &|b| put_u64(b, usize_at, u64::MAX));
        add("usize-minus-one", &|b| {
            let v = u64::from_le_bytes(b[usize_at..usize_at + 8].try_into().expect("8"));
            put_u64(b, usize_at, v - 1);
        });
        add("usize-plus-one", &|b| {
            let v = u64::from_le_bytes(b[usize_at..usize_at + 8].try_into().expect("8"));
            put_u64(b, usize_at, v + 1);
        });
        add("csize-max", &|b| put_u64(b, csize_at, u64::MAX));
        add("crc-flip", &|b| b[crc_at] ^= 0x01);
        add("data-flip", &|b| {
            b[data_at + (mid_len - (data_at - mid - 9)) / 2] ^= 0x40
        });
        add("chunk-record-length-max", &|b| {
            put_u64(b, mid + 1, u64::MAX)
        });
        add("chunk-record-length-plus-one", &|b| {
            put_u64(b, mid + 1, mid_len as u64 + 1)
        });
        if comp_len > 0 {
            add("compression-unknown", &|b| b[crc_at + 8] ^= 0x20);
        }
        // Single-byte flips (offset, mask) that killed `vinebench replay` before the
        // reader checked sizes and CRCs itself: 12 aborts allocating 9.4e11 to 8.5e18
        // bytes, 2 "capacity overflow" panics (found by flipping 400 random bytes of this
        // seed; the record lengths inside a chunk's decompressed data were trusted).
        if stem == "seed-zstd" {
            for (at, mask) in [
                (8107, 0xd2),
                (8327, 0x7b),
                (8420, 0x4c),
                (10177, 0xd9),
                (10868, 0x1d),
                (12711, 0x08),
                (20286, 0xb4),
                (25283, 0xae),
                (33989, 0x07),
                (37828, 0xfb),
                (42170, 0xc6),
                (43053, 0xd3),
                (46376, 0xfb),
                (52154, 0xf8),
            ] {
                add(&format!("flip-{at}-{mask:02x}"), &|b| b[at] ^= mask);
            }
        }
        // The header record: length, string length.
        add("header-length-max", &|b| put_u64(b, 9, u64::MAX));
        add("header-string-length-max", &|b| put_u32(b, 17, u32::MAX));
        // The first metadata record: name and map lengths.
        if let Some(&(m, _, _)) = recs.iter().find(|r| r.1 == 0x0c) {
            add("metadata-name-length-max", &|b| put_u32(b, m + 9, u32::MAX));
            let name_len = u32::from_le_bytes(seed[m + 9..m + 13].try_into().expect("4")) as usize;
            add("metadata-map-length-max", &|b| {
                put_u32(b, m + 13 + name_len, u32::MAX)
            });
            add("metadata-text-flip", &|b| b[m + 13 + name_len + 40] ^= 0x01);
        }
        // A message index claiming 4 GiB of entries.
        if let Some(&(mi, _, _)) = recs.iter().find(|r| r.1 == 0x07) {
            add("message-index-length-max", &|b| {
                put_u32(b, mi + 11, u32::MAX)
            });
        }
        // Truncations, the end magic, the data-section and summary CRCs.
        let n = seed.len();
        add("truncated-10pct", &|b| b.truncate(n * 9 / 10));
        add("truncated-50pct", &|b| b.truncate(n / 2));
        add("end-magic-missing", &|b| b.truncate(n - 8));
        add("end-magic-zeroed", &|b| b[n - 8..].fill(0));
        if let Some(&(de, _, _)) = recs.iter().find(|r| r.1 == 0x0f) {
            add("data-crc-flip", &|b| b[de + 9] ^= 0x01);
        }
        add("summary-crc-flip", &|b| b[n - 9] ^= 0x01);
        add("start-magic-flip", &|b| b[1] ^= 0x01);
    }
    // Inside an uncompressed chunk whose CRC is zeroed (no check): a channel's topic
    // length and a message record's length lie.
    {
        let recs = records(&plain);
        let (c, _, _) = *recs.iter().find(|r| r.1 == 0x06).expect("a chunk");
        let crc_at = c + 9 + 24;
        let comp_len =
            u32::from_le_bytes(plain[crc_at + 4..crc_at + 8].try_into().expect("4")) as usize;
        let inner = crc_at + 8 + comp_len + 8;
        let inner_recs = {
            let mut out = Vec::new();
            let end = c + 9 + recs.iter().find(|r| r.0 == c).expect("c").2;
            let mut p = inner;
            while p + 9 <= end {
                let len = u64::from_le_bytes(plain[p + 1..p + 9].try_into().expect("8")) as usize;
                out.push((p, plain[p]));
                p += 9 + len;
            }
            out
        };
        let mut add = |what: &str, f: &dyn Fn(&mut Vec<u8>)| {
            let mut b = plain.clone();
            put_u32(&mut b, crc_at, 0);
            f(&mut b);
            files.push((format!("seed-uncompressed--nocrc-{what}.mcap"), b));
        };
        if let Some(&(ch, _)) = inner_recs.iter().find(|r| r.1 == 0x04) {
            add("channel-topic-length-max", &|b| {
                put_u32(b, ch + 13, u32::MAX)
            });
            add("channel-metadata-length-max", &|b| {
                let tl = u32::from_le_bytes(b[ch + 13..ch + 17].try_into().expect("4")) as usize;
                let el = u32::from_le_bytes(b[ch + 17 + tl..ch + 21 + tl].try_into().expect("4"))
                    as usize;
                put_u32(b, ch + 21 + tl + el, u32::MAX);
            });
        }
        if let Some(&(s, _)) = inner_recs.iter().find(|r| r.1 == 0x03) {
            add("schema-data-length-max", &|b| {
                let nl = u32::from_le_bytes(b[s + 11..s + 15].try_into().expect("4")) as usize;
                let el =
                    u32::from_le_bytes(b[s + 15 + nl..s + 19 + nl].try_into().expect("4")) as usize;
                put_u32(b, s + 19 + nl + el, u32::MAX);
            });
        }
        if let Some(&(m, _)) = inner_recs.iter().find(|r| r.1 == 0x05) {
            add("message-length-max", &|b| put_u64(b, m + 1, u64::MAX));
        }
    }
    files.push(("empty.mcap".into(), Vec::new()));
    files.push(("magic-only.mcap".into(), reader::MAGIC.to_vec()));
    files.push((
        "not-mcap.mcap".into(),
        b"PK\x03\x04 a zip, not a recording".to_vec(),
    ));
    for (name, b) in &files {
        std::fs::write(dir.join(name), b).expect("write");
    }
}
