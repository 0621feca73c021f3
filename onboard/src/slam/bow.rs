//! Bag-of-words place recognition: the SLAM's bag-of-words loop-detection baseline.
//!
//! A faithful DBoW2 (Gálvez-López & Tardós, "Bags of Binary Words for Fast Place
//! Recognition in Image Sequences", T-RO 2012) with the loop-candidate logic of DLoopDetector
//! and ORB-SLAM2's `LoopClosing::DetectLoop`. In a vineyard the rows look alike, so a
//! bag-of-words detector accepts *false* loops between different rows that the AprilTag loop
//! closure never accepts; this module exists to show that, so it is neither tuned to fail nor
//! to succeed.
//!
//! In data-flow order:
//!
//! - [`Vocabulary`]: a hierarchical k-medians tree over ORB [`Descriptor`]s (branching `k`,
//!   depth `L`), k-means++ seeding from an internal seeded generator, per-bit majority
//!   centres; its leaves are the words, each with an idf weight `ln(N / n_i)`.
//!   [`Vocabulary::transform`] turns an image's descriptors into a tf-idf [`BowVector`]
//!   (L1-normalized); [`Vocabulary::transform_with_features`] adds the direct index
//!   ([`FeatureVector`]) for matching by vocabulary node.
//! - [`score`]: the L1 similarity `1 - ½‖a - b‖₁` of two bag-of-words vectors.
//! - [`Database`]: keyframe entries and the inverted file, [`Database::query`].
//! - [`LoopDetector`]: score thresholds normalized by an expected score, exclusion of recent
//!   keyframes, islands of consecutive keyframe ids, temporal consistency.
//!
//! ```
//! use vinebench_onboard::slam::Descriptor;
//! use vinebench_onboard::slam::bow::{Database, Vocabulary, VocabularyConfig, score};
//! // Four "images" of 50 distinct descriptors each.
//! let images: Vec<Vec<Descriptor>> = (0..4u64)
//!     .map(|i| {
//!         (0..50u64)
//!             .map(|j| {
//!                 let x = (i * 50 + j + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
//!                 Descriptor([x, x.rotate_left(17), !x, x.rotate_right(9)])
//!             })
//!             .collect()
//!     })
//!     .collect();
//! let cfg = VocabularyConfig { branching: 4, depth: 3, ..VocabularyConfig::default() };
//! let voc = Vocabulary::train(&images, &cfg)?;
//! let a = voc.transform(&images[0]);
//! assert!((score(&a, &a) - 1.0).abs() < 1e-12);
//! let mut db = Database::new();
//! for (id, img) in images.iter().enumerate() {
//!     db.add(id as u32, voc.transform(img))?;
//! }
//! assert_eq!(db.query(&a, 1, |_| false)[0].0, 0);
//! # Ok::<(), vinebench_onboard::slam::bow::BowError>(())
//! ```

use std::collections::BTreeMap;
use std::io::{Read, Write};

use rayon::prelude::*;
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::orb::{Descriptor, hamming};
use super::{ConfigError, check};

/// Magic header of a vocabulary file: `VBVOC` and the format version digit.
pub const VOCABULARY_MAGIC: &[u8; 6] = b"VBVOC1";

/// The magic without its version digit.
const MAGIC_STEM: &[u8] = b"VBVOC";

/// Default branching factor `k` (DBoW2's and ORB-SLAM's vocabularies).
pub const DEFAULT_BRANCHING: usize = 10;

/// Default depth `L` (ORB-SLAM's vocabulary has `k = 10`, `L = 6`; DBoW2's demo `L = 5`).
pub const DEFAULT_DEPTH: usize = 5;

/// Default seed of the k-means++ seeding.
pub const DEFAULT_SEED: u64 = 0xB0_B5EE_D0F0_0D5E;

/// Default cap on k-medians iterations per node (DBoW2 iterates until no descriptor changes
/// cluster; the cap only guards against cycling among equal-cost assignments).
pub const DEFAULT_MAX_ITERATIONS: usize = 100;

/// Largest branching factor accepted (a node's children are scanned linearly).
pub const MAX_BRANCHING: usize = 1024;

/// Largest depth accepted.
pub const MAX_DEPTH: usize = 16;

/// Below this many descriptors a node's k-medians steps are not split across threads.
const PAR_MIN_LEN: usize = 2048;

/// Bytes of one node in the vocabulary file without its weight: parent, descriptor, kind.
const NODE_MIN_BYTES: usize = 4 + 32 + 1;

/// A word of the vocabulary (a leaf of the tree), numbered 0.. in node order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct WordId(pub u32);

/// A node of the vocabulary tree; node 0 is the root, children follow their parent and the
/// children of one node are numbered consecutively (DBoW2's order).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct NodeId(pub u32);

/// What went wrong training, reading or using a vocabulary or database.
#[derive(Debug, Error)]
pub enum BowError {
    /// A setting out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Training needs at least one descriptor.
    #[error("vocabulary training set holds no descriptor")]
    EmptyTrainingSet,
    /// Training set beyond the 32-bit node and document counts.
    #[error("vocabulary training set too large: {0}")]
    TooLarge(String),
    /// Reading or writing a vocabulary file failed.
    #[error("vocabulary file: {0}")]
    Io(#[from] std::io::Error),
    /// A vocabulary file is not what this version writes.
    #[error("vocabulary file: expected {expected}, found {found}")]
    Format {
        /// What the reader expected at that point.
        expected: String,
        /// What it found instead.
        found: String,
    },
    /// [`Database::add`] with an id the database already holds.
    #[error("bag-of-words database already holds entry {0}")]
    DuplicateEntry(u32),
}

/// How [`Vocabulary::train`] builds the tree.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct VocabularyConfig {
    /// Branching factor `k`: clusters per node.
    pub branching: usize,
    /// Depth `L`: levels below the root (at most `k^L` words). A node with at most `k`
    /// descriptors gets one leaf per distinct descriptor, so a small training set gives a
    /// shallower tree by itself.
    pub depth: usize,
    /// Seed of the k-means++ seeding; the same seed gives a bit-identical vocabulary,
    /// whatever the number of threads.
    pub seed: u64,
    /// Cap on k-medians iterations per node (assign, then recompute the centres).
    pub max_iterations: usize,
}

impl Default for VocabularyConfig {
    fn default() -> Self {
        VocabularyConfig {
            branching: DEFAULT_BRANCHING,
            depth: DEFAULT_DEPTH,
            seed: DEFAULT_SEED,
            max_iterations: DEFAULT_MAX_ITERATIONS,
        }
    }
}

impl VocabularyConfig {
    /// `Err` naming the first setting out of range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            (2..=MAX_BRANCHING).contains(&self.branching),
            "bow vocabulary branching must be in 2..=1024",
        )?;
        check(
            (1..=MAX_DEPTH).contains(&self.depth),
            "bow vocabulary depth must be in 1..=16",
        )?;
        check(
            self.max_iterations >= 1,
            "bow vocabulary max_iterations must be at least 1",
        )
    }
}

/// splitmix64 (Steele, Lea & Flood 2014): the seeded generator of the k-means++ seeding.
#[derive(Clone, Debug)]
pub(super) struct SplitMix64(pub(super) u64);

impl SplitMix64 {
    pub(super) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n > 0`), by Lemire's multiply-shift.
    pub(super) fn below(&mut self, n: u64) -> u64 {
        ((u128::from(self.next_u64()) * u128::from(n)) >> 64) as u64
    }
}

/// The seed of child `i` of a node seeded `seed`: each subtree has its own stream, so the
/// tree does not depend on the order threads finish in.
fn child_seed(seed: u64, i: usize) -> u64 {
    SplitMix64(seed ^ (i as u64 + 1).wrapping_mul(0xD1B5_4A32_D192_ED03)).next_u64()
}

/// `SPREAD[b]` has byte `j` equal to bit `j` of `b`: adding it counts 8 bits at once.
const SPREAD: [u64; 256] = {
    let mut t = [0u64; 256];
    let mut b = 0;
    while b < 256 {
        let mut v = 0u64;
        let mut j = 0;
        while j < 8 {
            if (b >> j) & 1 == 1 {
                v |= 1 << (8 * j);
            }
            j += 1;
        }
        t[b] = v;
        b += 1;
    }
    t
};

/// Per-bit set counts of a set of descriptors: eight 8-bit counters per `u64`, flushed into
/// 32-bit totals every 255 descriptors.
#[derive(Clone)]
struct BitCounts {
    lanes: [u64; 32],
    pending: u32,
    totals: [u32; 256],
    n: u32,
}

impl BitCounts {
    fn new() -> BitCounts {
        BitCounts {
            lanes: [0; 32],
            pending: 0,
            totals: [0; 256],
            n: 0,
        }
    }

    fn add(&mut self, d: &Descriptor) {
        for (w, word) in d.0.iter().enumerate() {
            for (j, b) in word.to_le_bytes().iter().enumerate() {
                self.lanes[w * 8 + j] += SPREAD[usize::from(*b)];
            }
        }
        self.pending += 1;
        self.n += 1;
        if self.pending == 255 {
            self.flush();
        }
    }

    fn flush(&mut self) {
        for (i, lane) in self.lanes.iter_mut().enumerate() {
            for j in 0..8 {
                self.totals[i * 8 + j] += ((*lane >> (8 * j)) & 0xff) as u32;
            }
            *lane = 0;
        }
        self.pending = 0;
    }

    /// The per-bit majority (DBoW2's `FORB::meanValue`): bit `i` is set when at least half
    /// of the descriptors have it set (a tie sets it).
    fn majority(mut self) -> Descriptor {
        self.flush();
        let mut out = [0u64; 4];
        for (bit, &count) in self.totals.iter().enumerate() {
            if 2 * u64::from(count) >= u64::from(self.n) {
                out[bit / 64] |= 1 << (bit % 64);
            }
        }
        Descriptor(out)
    }
}

/// Index of the centre nearest to `d` (the first one on ties).
fn nearest(d: &Descriptor, centers: &[Descriptor]) -> usize {
    let mut best = (u32::MAX, 0);
    for (i, c) in centers.iter().enumerate() {
        let dist = hamming(d, c);
        if dist < best.0 {
            best = (dist, i);
        }
    }
    best.1
}

/// k-means++ seeding (Arthur & Vassilvitskii 2007) as DBoW2's `initiateClustersKMpp`: the
/// first centre uniformly, each next one with probability proportional to the squared
/// Hamming distance to the nearest centre so far; stops early when every descriptor
/// coincides with a centre.
fn seed_centers(members: &[Descriptor], k: usize, rng: &mut SplitMix64) -> Vec<Descriptor> {
    let first = members[rng.below(members.len() as u64) as usize];
    let mut centers = vec![first];
    let sq = |d: u32| u64::from(d) * u64::from(d);
    let mut min_d2: Vec<u64> = members
        .par_iter()
        .with_min_len(PAR_MIN_LEN)
        .map(|d| sq(hamming(d, &first)))
        .collect();
    while centers.len() < k {
        let total: u64 = min_d2.iter().sum();
        if total == 0 {
            break;
        }
        let cut = 1 + rng.below(total);
        let mut acc = 0;
        let mut pick = members.len() - 1;
        for (i, &w) in min_d2.iter().enumerate() {
            acc += w;
            if acc >= cut {
                pick = i;
                break;
            }
        }
        let c = members[pick];
        centers.push(c);
        min_d2
            .par_iter_mut()
            .zip(members.par_iter())
            .with_min_len(PAR_MIN_LEN)
            .for_each(|(m, d)| {
                if *m > 0 {
                    *m = (*m).min(sq(hamming(d, &c)));
                }
            });
    }
    centers
}

/// The nearest centre of every member.
fn assign(members: &[Descriptor], centers: &[Descriptor]) -> Vec<u32> {
    members
        .par_iter()
        .with_min_len(PAR_MIN_LEN)
        .map(|d| nearest(d, centers) as u32)
        .collect()
}

/// Each centre becomes the per-bit majority of its members; a centre left without members
/// keeps its value. Chunks are counted in parallel and their integer counts summed, so the
/// result does not depend on the threads.
fn update_centers(members: &[Descriptor], assignment: &[u32], centers: &mut [Descriptor]) {
    let k = centers.len();
    let counts = members
        .par_chunks(PAR_MIN_LEN)
        .zip(assignment.par_chunks(PAR_MIN_LEN))
        .map(|(ds, cs)| {
            let mut counts = vec![BitCounts::new(); k];
            for (d, &c) in ds.iter().zip(cs) {
                counts[c as usize].add(d);
            }
            counts
                .into_iter()
                .map(|mut c| {
                    c.flush();
                    (c.totals, c.n)
                })
                .collect::<Vec<_>>()
        })
        .reduce(
            || vec![([0u32; 256], 0u32); k],
            |mut a, b| {
                for ((ta, na), (tb, nb)) in a.iter_mut().zip(b) {
                    ta.iter_mut().zip(tb).for_each(|(x, y)| *x += y);
                    *na += nb;
                }
                a
            },
        );
    for (center, (totals, n)) in centers.iter_mut().zip(counts) {
        if n > 0 {
            let mut c = BitCounts::new();
            c.totals = totals;
            c.n = n;
            *center = c.majority();
        }
    }
}

/// k-medians of `members` into at most `k` clusters (DBoW2's `HKmeansStep`): k-means++
/// seeding, then assignment and per-bit-majority centres until no member changes cluster (or
/// `max_iterations`). Returns the non-empty clusters, each centre with its members; every
/// member is nearest to its own centre (first on ties).
fn k_medians(
    members: &[Descriptor],
    k: usize,
    seed: u64,
    max_iterations: usize,
) -> Vec<(Descriptor, Vec<Descriptor>)> {
    let mut rng = SplitMix64(seed);
    let mut centers = seed_centers(members, k, &mut rng);
    let mut assignment = assign(members, &centers);
    for _ in 1..max_iterations {
        update_centers(members, &assignment, &mut centers);
        let next = assign(members, &centers);
        if next == assignment {
            break;
        }
        assignment = next;
    }
    let mut groups = vec![Vec::new(); centers.len()];
    for (d, &c) in members.iter().zip(&assignment) {
        groups[c as usize].push(*d);
    }
    centers
        .into_iter()
        .zip(groups)
        .filter(|(_, g)| !g.is_empty())
        .collect()
}

/// A node of the tree under construction.
struct Cluster {
    center: Descriptor,
    children: Vec<Cluster>,
}

/// The children (at depth `level`) of a node holding `members`, with their subtrees. At most
/// `k` members: one leaf per distinct member (DBoW2's trivial case, less the duplicates,
/// which no descriptor could reach). A child with one distinct member, or at depth `L`, is
/// a leaf.
fn split(
    members: Vec<Descriptor>,
    level: usize,
    seed: u64,
    cfg: &VocabularyConfig,
) -> Vec<Cluster> {
    let groups: Vec<(Descriptor, Vec<Descriptor>)> = if members.len() <= cfg.branching {
        let mut distinct: Vec<Descriptor> = Vec::with_capacity(members.len());
        for d in members {
            if !distinct.contains(&d) {
                distinct.push(d);
            }
        }
        distinct.into_iter().map(|d| (d, vec![d])).collect()
    } else {
        k_medians(&members, cfg.branching, seed, cfg.max_iterations)
    };
    groups
        .into_par_iter()
        .enumerate()
        .map(|(i, (center, group))| {
            let uniform = group.iter().all(|d| *d == group[0]);
            let children = if level < cfg.depth && !uniform {
                split(group, level + 1, child_seed(seed, i), cfg)
            } else {
                Vec::new()
            };
            Cluster { center, children }
        })
        .collect()
}

/// A vocabulary tree: hierarchical k-medians over ORB descriptors, leaves as words with idf
/// weights (DBoW2's `TemplatedVocabulary` with TF-IDF weighting and L1 scoring).
///
/// Stored as parallel arrays over the nodes; the children of a node are consecutive, so a
/// descent compares a descriptor with one contiguous slice of centres per level.
#[derive(Clone, Debug, PartialEq)]
pub struct Vocabulary {
    branching: usize,
    depth: usize,
    n_docs: u32,
    /// Centre of each node (the root's is unused, zero).
    centers: Vec<Descriptor>,
    /// Parent of each node (the root's is 0).
    parents: Vec<u32>,
    /// First child of each node (0 for a leaf).
    first_child: Vec<u32>,
    /// Number of children of each node (0 for a leaf).
    n_children: Vec<u32>,
    /// Depth of each node (root 0).
    depths: Vec<u32>,
    /// Word of each node (`u32::MAX` for internal nodes).
    node_word: Vec<u32>,
    /// Leaf node of each word.
    word_node: Vec<u32>,
    /// idf weight `ln(N / n_i)` of each word.
    weights: Vec<f64>,
}

impl Vocabulary {
    /// Trains a vocabulary on `images` (each the descriptors of one training image, a
    /// "document" for the idf weights): hierarchical k-medians with k-means++ seeding over
    /// all descriptors, then `ln(N / n_i)` per word, `N` the number of images and `n_i` the
    /// number of images with a descriptor in word `i` (0 for a word no image reaches).
    ///
    /// Deterministic: the same `cfg` gives a bit-identical vocabulary whatever the size of
    /// the rayon thread pool it runs in.
    pub fn train(
        images: &[Vec<Descriptor>],
        cfg: &VocabularyConfig,
    ) -> Result<Vocabulary, BowError> {
        cfg.validate()?;
        let all: Vec<Descriptor> = images.iter().flatten().copied().collect();
        if all.is_empty() {
            return Err(BowError::EmptyTrainingSet);
        }
        let n_docs = u32::try_from(images.len())
            .map_err(|_| BowError::TooLarge(format!("{} images", images.len())))?;
        if (all.len() as u128) * (cfg.depth as u128) >= u128::from(u32::MAX) {
            return Err(BowError::TooLarge(format!(
                "{} descriptors at depth {}",
                all.len(),
                cfg.depth
            )));
        }
        let tree = split(all, 1, cfg.seed, cfg);
        let mut voc = Vocabulary::from_tree(cfg.branching, cfg.depth, n_docs, &tree);
        let per_image: Vec<Vec<u32>> = images
            .par_iter()
            .map(|img| {
                let mut words: Vec<u32> = img.iter().map(|d| voc.word(d).0).collect();
                words.sort_unstable();
                words.dedup();
                words
            })
            .collect();
        let mut docs_with = vec![0u32; voc.word_node.len()];
        for w in per_image.iter().flatten() {
            docs_with[*w as usize] += 1;
        }
        voc.weights = docs_with
            .iter()
            .map(|&ni| {
                if ni > 0 {
                    (f64::from(n_docs) / f64::from(ni)).ln()
                } else {
                    0.0
                }
            })
            .collect();
        Ok(voc)
    }

    /// The node arrays of a built tree, in DBoW2's order (a node's children created
    /// together, then each child's subtree in turn); words numbered in node order.
    fn from_tree(branching: usize, depth: usize, n_docs: u32, root: &[Cluster]) -> Vocabulary {
        let mut voc = Vocabulary {
            branching,
            depth,
            n_docs,
            centers: vec![Descriptor::default()],
            parents: vec![0],
            first_child: vec![0],
            n_children: vec![0],
            depths: vec![0],
            node_word: vec![u32::MAX],
            word_node: Vec::new(),
            weights: Vec::new(),
        };
        fn place(voc: &mut Vocabulary, children: &[Cluster], parent: u32) {
            let first = voc.centers.len() as u32;
            let depth = voc.depths[parent as usize] + 1;
            for c in children {
                voc.centers.push(c.center);
                voc.parents.push(parent);
                voc.first_child.push(0);
                voc.n_children.push(0);
                voc.depths.push(depth);
                voc.node_word.push(u32::MAX);
            }
            voc.first_child[parent as usize] = first;
            voc.n_children[parent as usize] = children.len() as u32;
            for (i, c) in children.iter().enumerate() {
                if !c.children.is_empty() {
                    place(voc, &c.children, first + i as u32);
                }
            }
        }
        place(&mut voc, root, 0);
        voc.number_words();
        voc.weights = vec![0.0; voc.word_node.len()];
        voc
    }

    /// Numbers the leaves (nodes without children, not the root) in node order.
    fn number_words(&mut self) {
        self.word_node.clear();
        for node in 1..self.centers.len() {
            if self.n_children[node] == 0 {
                self.node_word[node] = self.word_node.len() as u32;
                self.word_node.push(node as u32);
            } else {
                self.node_word[node] = u32::MAX;
            }
        }
    }

    /// Branching factor `k` the vocabulary was trained with.
    pub fn branching(&self) -> usize {
        self.branching
    }

    /// Depth `L` the vocabulary was trained with (its leaves are at depth `L` or above).
    pub fn depth(&self) -> usize {
        self.depth
    }

    /// Number of training images (documents) behind the idf weights.
    pub fn training_images(&self) -> u32 {
        self.n_docs
    }

    /// Number of words (leaves).
    pub fn n_words(&self) -> usize {
        self.word_node.len()
    }

    /// Number of nodes, the root included.
    pub fn n_nodes(&self) -> usize {
        self.centers.len()
    }

    /// idf weight of `word` (`None` outside the vocabulary).
    pub fn word_weight(&self, word: WordId) -> Option<f64> {
        self.weights.get(word.0 as usize).copied()
    }

    /// Centre of `word`'s leaf (`None` outside the vocabulary).
    pub fn word_center(&self, word: WordId) -> Option<Descriptor> {
        let node = *self.word_node.get(word.0 as usize)?;
        Some(self.centers[node as usize])
    }

    /// Leaf node of `word` (`None` outside the vocabulary).
    pub fn word_node(&self, word: WordId) -> Option<NodeId> {
        self.word_node.get(word.0 as usize).map(|&n| NodeId(n))
    }

    /// The leaf reached from the root by moving, at each level, to the child whose centre
    /// is nearest in Hamming distance (the first on ties), and the node passed at depth
    /// `stop_depth` (the leaf when it lies above that depth; the root for depth 0).
    fn descend(&self, d: &Descriptor, stop_depth: u32) -> (u32, u32) {
        let mut node = 0usize;
        let mut at_depth = 0u32;
        loop {
            let n = self.n_children[node] as usize;
            if n == 0 {
                break;
            }
            let first = self.first_child[node] as usize;
            node = first + nearest(d, &self.centers[first..first + n]);
            if self.depths[node] <= stop_depth {
                at_depth = node as u32;
            }
        }
        (node as u32, at_depth)
    }

    /// The word of one descriptor (greedy descent, nearest child at each level).
    pub fn word(&self, d: &Descriptor) -> WordId {
        WordId(self.node_word[self.descend(d, 0).0 as usize])
    }

    /// The bag-of-words vector of one image's descriptors: each descriptor adds its word's
    /// idf weight (words of weight 0 are skipped, as DBoW2 does), and the sums are
    /// L1-normalized (tf-idf with the tf taken relative to the vector's total).
    pub fn transform(&self, descriptors: &[Descriptor]) -> BowVector {
        let words: Vec<u32> = descriptors.iter().map(|d| self.word(d).0).collect();
        self.bow_from_words(words)
    }

    /// [`transform`](Self::transform) and the direct index: for every feature that counts
    /// (its word's weight is positive), its index filed under its ancestor node at depth
    /// `L - levels_up` (the leaf itself when the leaf lies higher; the root when
    /// `levels_up >= L`), as ORB-SLAM does with `levels_up = 4` to restrict descriptor
    /// matching to features under the same node.
    pub fn transform_with_features(
        &self,
        descriptors: &[Descriptor],
        levels_up: usize,
    ) -> (BowVector, FeatureVector) {
        let stop_depth = self.depth.saturating_sub(levels_up) as u32;
        let mut words = Vec::with_capacity(descriptors.len());
        let mut features = FeatureVector::default();
        for (i, d) in descriptors.iter().enumerate() {
            let (leaf, node) = self.descend(d, stop_depth);
            let word = self.node_word[leaf as usize];
            if self.weights[word as usize] > 0.0 {
                features.0.entry(NodeId(node)).or_default().push(i);
            }
            words.push(word);
        }
        (self.bow_from_words(words), features)
    }

    /// The L1-normalized tf-idf vector of a bag of words.
    fn bow_from_words(&self, mut words: Vec<u32>) -> BowVector {
        words.sort_unstable();
        let mut entries: Vec<(WordId, f64)> = Vec::new();
        for run in words.chunk_by(|a, b| a == b) {
            let w = self.weights[run[0] as usize];
            if w > 0.0 {
                entries.push((WordId(run[0]), run.len() as f64 * w));
            }
        }
        BowVector::normalized(entries)
    }

    /// The vocabulary file: [`VOCABULARY_MAGIC`], then little-endian `u32` branching,
    /// depth, training images and node count (root included), then for every node after the
    /// root its parent (`u32`), its centre (4 × `u64`), a kind byte (0 internal, 1 leaf) and,
    /// for a leaf, its idf weight (`f64`), and last an FNV-1a 64 checksum (`u64`) of every
    /// byte after the magic.
    pub fn to_bytes(&self) -> Vec<u8> {
        let n = self.centers.len();
        let mut out = Vec::with_capacity(6 + 16 + n * (NODE_MIN_BYTES + 8) + 8);
        out.extend_from_slice(VOCABULARY_MAGIC);
        for v in [
            self.branching as u32,
            self.depth as u32,
            self.n_docs,
            n as u32,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for node in 1..n {
            out.extend_from_slice(&self.parents[node].to_le_bytes());
            for w in self.centers[node].0 {
                out.extend_from_slice(&w.to_le_bytes());
            }
            match self.node_word[node] {
                u32::MAX => out.push(0),
                word => {
                    out.push(1);
                    out.extend_from_slice(&self.weights[word as usize].to_le_bytes());
                }
            }
        }
        let sum = fnv1a(&out[VOCABULARY_MAGIC.len()..]);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// Writes the vocabulary file (see [`to_bytes`](Self::to_bytes)).
    pub fn write(&self, mut w: impl Write) -> Result<(), BowError> {
        w.write_all(&self.to_bytes())?;
        w.flush()?;
        Ok(())
    }

    /// Reads a vocabulary file written by [`write`](Self::write).
    pub fn read(mut r: impl Read) -> Result<Vocabulary, BowError> {
        let mut bytes = Vec::new();
        r.read_to_end(&mut bytes)?;
        Vocabulary::from_bytes(&bytes)
    }

    /// Parses a vocabulary file (see [`to_bytes`](Self::to_bytes)), checking the magic,
    /// the checksum and the tree's structure.
    pub fn from_bytes(bytes: &[u8]) -> Result<Vocabulary, BowError> {
        let magic_len = VOCABULARY_MAGIC.len();
        let head = &bytes[..bytes.len().min(magic_len)];
        if head != VOCABULARY_MAGIC {
            if head.len() == magic_len && head.starts_with(MAGIC_STEM) {
                return Err(format_error(
                    "format version 1 (magic VBVOC1)",
                    format!("version {:?}", char::from(head[magic_len - 1])),
                ));
            }
            return Err(format_error(
                "magic VBVOC1",
                format!("{:?}", String::from_utf8_lossy(head)),
            ));
        }
        if bytes.len() < magic_len + 16 + 8 {
            return Err(format_error(
                "a header and a checksum (at least 30 bytes)",
                format!("{} bytes", bytes.len()),
            ));
        }
        let (body, tail) = bytes[magic_len..].split_at(bytes.len() - magic_len - 8);
        let mut stored = [0u8; 8];
        stored.copy_from_slice(tail);
        let stored = u64::from_le_bytes(stored);
        let computed = fnv1a(body);
        if stored != computed {
            return Err(format_error(
                format!("checksum {stored:#018x}"),
                format!("{computed:#018x} (file corrupted or truncated)"),
            ));
        }
        let mut c = ByteCursor {
            bytes: body,
            pos: 0,
        };
        let branching = c.u32("branching")? as usize;
        let depth = c.u32("depth")? as usize;
        let n_docs = c.u32("training image count")?;
        let n_nodes = c.u32("node count")? as usize;
        if !(2..=MAX_BRANCHING).contains(&branching) {
            return Err(format_error("branching in 2..=1024", branching.to_string()));
        }
        if !(1..=MAX_DEPTH).contains(&depth) {
            return Err(format_error("depth in 1..=16", depth.to_string()));
        }
        if n_nodes < 2 || (n_nodes - 1) > body.len() / NODE_MIN_BYTES {
            return Err(format_error(
                format!("a node count in 2..={}", body.len() / NODE_MIN_BYTES + 1),
                n_nodes.to_string(),
            ));
        }
        let mut voc = Vocabulary {
            branching,
            depth,
            n_docs,
            centers: Vec::with_capacity(n_nodes),
            parents: Vec::with_capacity(n_nodes),
            first_child: Vec::with_capacity(n_nodes),
            n_children: Vec::with_capacity(n_nodes),
            depths: Vec::with_capacity(n_nodes),
            node_word: Vec::with_capacity(n_nodes),
            word_node: Vec::new(),
            weights: Vec::new(),
        };
        voc.centers.push(Descriptor::default());
        voc.parents.push(0);
        voc.first_child.push(0);
        voc.n_children.push(0);
        voc.depths.push(0);
        voc.node_word.push(u32::MAX);
        let mut is_leaf = vec![false];
        let mut leaf_weights = Vec::new();
        for node in 1..n_nodes {
            let parent = c.u32("node parent")? as usize;
            if parent >= node || is_leaf[parent] {
                return Err(format_error(
                    format!("node {node}'s parent to be an earlier internal node"),
                    format!("parent {parent}"),
                ));
            }
            let mut words = [0u64; 4];
            for w in &mut words {
                *w = c.u64("node centre")?;
            }
            let kind = c.u8("node kind")?;
            let leaf = match kind {
                0 => false,
                1 => true,
                k => return Err(format_error("node kind 0 or 1", k.to_string())),
            };
            if leaf {
                let weight = f64::from_bits(c.u64("leaf weight")?);
                if !(weight.is_finite() && weight >= 0.0) {
                    return Err(format_error(
                        format!("a finite non-negative weight at node {node}"),
                        weight.to_string(),
                    ));
                }
                leaf_weights.push(weight);
            }
            let (first, count) = (voc.first_child[parent], voc.n_children[parent]);
            if count == 0 {
                voc.first_child[parent] = node as u32;
            } else if (first + count) as usize != node {
                return Err(format_error(
                    format!("the children of node {parent} to be consecutive"),
                    format!("node {node} after {} of them at {first}", count),
                ));
            }
            if count as usize == branching {
                return Err(format_error(
                    format!("at most {branching} children under node {parent}"),
                    "more".to_string(),
                ));
            }
            voc.n_children[parent] = count + 1;
            let node_depth = voc.depths[parent] + 1;
            if node_depth as usize > depth {
                return Err(format_error(
                    format!("nodes at depth 1..={depth}"),
                    format!("node {node} at depth {node_depth}"),
                ));
            }
            voc.centers.push(Descriptor(words));
            voc.parents.push(parent as u32);
            voc.first_child.push(0);
            voc.n_children.push(0);
            voc.depths.push(node_depth);
            voc.node_word.push(u32::MAX);
            is_leaf.push(leaf);
        }
        if c.pos != body.len() {
            return Err(format_error(
                format!("the checksum after {n_nodes} nodes"),
                format!("{} more bytes", body.len() - c.pos),
            ));
        }
        if let Some(node) = (0..n_nodes).find(|&n| !is_leaf[n] && voc.n_children[n] == 0) {
            return Err(format_error(
                format!("internal node {node} to have children"),
                "none".to_string(),
            ));
        }
        voc.number_words();
        voc.weights = leaf_weights;
        Ok(voc)
    }
}

/// FNV-1a, 64 bits.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xCBF2_9CE4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01B3)
    })
}

fn format_error(expected: impl Into<String>, found: impl Into<String>) -> BowError {
    BowError::Format {
        expected: expected.into(),
        found: found.into(),
    }
}

/// Reads little-endian fields of a vocabulary file body.
struct ByteCursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl ByteCursor<'_> {
    fn take<const N: usize>(&mut self, what: &str) -> Result<[u8; N], BowError> {
        let Some(slice) = self.bytes.get(self.pos..self.pos + N) else {
            return Err(format_error(
                format!("{what} ({N} bytes at body offset {})", self.pos),
                "the end of the file".to_string(),
            ));
        };
        let mut out = [0u8; N];
        out.copy_from_slice(slice);
        self.pos += N;
        Ok(out)
    }

    fn u8(&mut self, what: &str) -> Result<u8, BowError> {
        Ok(self.take::<1>(what)?[0])
    }

    fn u32(&mut self, what: &str) -> Result<u32, BowError> {
        Ok(u32::from_le_bytes(self.take(what)?))
    }

    fn u64(&mut self, what: &str) -> Result<u64, BowError> {
        Ok(u64::from_le_bytes(self.take(what)?))
    }
}

/// A bag-of-words vector: sparse word → weight, sorted by word, weights positive and summing
/// to 1 (or empty).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BowVector {
    entries: Vec<(WordId, f64)>,
}

impl BowVector {
    /// The vector of `weights` (any order; a word's weights are summed, non-positive and
    /// non-finite totals dropped), L1-normalized.
    pub fn from_weights(mut weights: Vec<(WordId, f64)>) -> BowVector {
        weights.sort_by_key(|e| e.0);
        let mut entries: Vec<(WordId, f64)> = Vec::with_capacity(weights.len());
        for (w, v) in weights {
            match entries.last_mut() {
                Some(last) if last.0 == w => last.1 += v,
                _ => entries.push((w, v)),
            }
        }
        entries.retain(|e| e.1.is_finite() && e.1 > 0.0);
        BowVector::normalized(entries)
    }

    /// `entries` (sorted, unique, positive) divided by their sum.
    fn normalized(mut entries: Vec<(WordId, f64)>) -> BowVector {
        let total: f64 = entries.iter().map(|e| e.1).sum();
        if total > 0.0 {
            entries.iter_mut().for_each(|e| e.1 /= total);
        } else {
            entries.clear();
        }
        BowVector { entries }
    }

    /// Number of distinct words.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// No word at all.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The words and their weights, by increasing word.
    pub fn iter(&self) -> impl Iterator<Item = (WordId, f64)> + '_ {
        self.entries.iter().copied()
    }

    /// Weight of `word` (`None` when absent).
    pub fn get(&self, word: WordId) -> Option<f64> {
        self.entries
            .binary_search_by_key(&word, |e| e.0)
            .ok()
            .map(|i| self.entries[i].1)
    }
}

/// L1 similarity of two bag-of-words vectors, DBoW2's `L1Scoring`: `1 - ½‖a - b‖₁` for
/// L1-normalized vectors, in `[0, 1]` (1 for equal vectors, 0 for vectors without a common
/// word). Computed over the common words as `Σ min(a_i, b_i)`, which equals DBoW2's
/// `-½ Σ (|a_i - b_i| - |a_i| - |b_i|)` for non-negative weights.
pub fn score(a: &BowVector, b: &BowVector) -> f64 {
    let (mut i, mut j, mut s) = (0, 0, 0.0);
    while i < a.entries.len() && j < b.entries.len() {
        let (wa, va) = a.entries[i];
        let (wb, vb) = b.entries[j];
        match wa.cmp(&wb) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                s += va.min(vb);
                i += 1;
                j += 1;
            }
        }
    }
    s
}

/// The direct index of an image: vocabulary node → indices (ascending) of the image's
/// features under it, at the level chosen in [`Vocabulary::transform_with_features`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FeatureVector(BTreeMap<NodeId, Vec<usize>>);

impl FeatureVector {
    /// Number of nodes with features.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// No feature at all.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// The nodes, increasing, with their feature indices.
    pub fn iter(&self) -> impl Iterator<Item = (NodeId, &[usize])> + '_ {
        self.0.iter().map(|(n, f)| (*n, f.as_slice()))
    }

    /// Feature indices under `node` (`None` when none).
    pub fn get(&self, node: NodeId) -> Option<&[usize]> {
        self.0.get(&node).map(Vec::as_slice)
    }

    /// The nodes both vectors have features under, increasing, with the features of each
    /// (the candidate pairs of ORB-SLAM's `SearchByBoW`).
    pub fn common<'a>(
        &'a self,
        other: &'a FeatureVector,
    ) -> impl Iterator<Item = (NodeId, &'a [usize], &'a [usize])> + 'a {
        self.0
            .iter()
            .filter_map(|(n, a)| other.0.get(n).map(|b| (*n, a.as_slice(), b.as_slice())))
    }
}

/// Keyframe bag-of-words vectors with an inverted file (word → entries holding it), DBoW2's
/// `TemplatedDatabase` without the direct index.
#[derive(Clone, Debug, Default)]
pub struct Database {
    /// Caller's id of each entry, in insertion order.
    ids: Vec<u32>,
    /// Vector of each entry.
    bows: Vec<BowVector>,
    /// Entry index of each id.
    index: FxHashMap<u32, u32>,
    /// For each word, the entries holding it (entry index, weight), in insertion order.
    inverted: Vec<Vec<(u32, f64)>>,
}

impl Database {
    /// An empty database.
    pub fn new() -> Database {
        Database::default()
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    /// No entry.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// Adds keyframe `id` with its vector.
    pub fn add(&mut self, id: u32, bow: BowVector) -> Result<(), BowError> {
        if self.index.contains_key(&id) {
            return Err(BowError::DuplicateEntry(id));
        }
        let entry = self.ids.len() as u32;
        for (w, v) in bow.iter() {
            let w = w.0 as usize;
            if w >= self.inverted.len() {
                self.inverted.resize_with(w + 1, Vec::new);
            }
            self.inverted[w].push((entry, v));
        }
        self.index.insert(id, entry);
        self.ids.push(id);
        self.bows.push(bow);
        Ok(())
    }

    /// The vector of entry `id` (`None` when absent).
    pub fn get(&self, id: u32) -> Option<&BowVector> {
        self.index.get(&id).map(|&e| &self.bows[e as usize])
    }

    /// The ids of the entries, in insertion order.
    pub fn ids(&self) -> &[u32] {
        &self.ids
    }

    /// The best `max_results` entries for `bow` by [`score`] (equal to it bit for bit),
    /// highest first, ties by increasing id; only entries sharing a word with `bow` and not
    /// `exclude`d are considered (DBoW2's `queryL1` over the inverted file).
    pub fn query(
        &self,
        bow: &BowVector,
        max_results: usize,
        exclude: impl Fn(u32) -> bool,
    ) -> Vec<(u32, f64)> {
        let mut acc = vec![0.0f64; self.ids.len()];
        let mut hit = vec![false; self.ids.len()];
        for (w, q) in bow.iter() {
            let Some(row) = self.inverted.get(w.0 as usize) else {
                continue;
            };
            for &(e, v) in row {
                acc[e as usize] += q.min(v);
                hit[e as usize] = true;
            }
        }
        let mut out: Vec<(u32, f64)> = (0..self.ids.len())
            .filter(|&e| hit[e] && !exclude(self.ids[e]))
            .map(|e| (self.ids[e], acc[e]))
            .collect();
        out.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        out.truncate(max_results);
        out
    }
}

/// How [`LoopDetector`] picks loop candidates (DLoopDetector's parameters, ORB-SLAM2's
/// island ratio and consistency).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoopDetectorConfig {
    /// Database results considered per query (DLoopDetector's `max_db_results`).
    pub max_results: usize,
    /// Absolute floor on a candidate's score.
    pub min_score: f64,
    /// A candidate's score must reach this fraction of the normalizer score passed to
    /// [`LoopDetector::detect`] (DLoopDetector's `alpha` on the normalized similarity
    /// `s / s_prev`, 0.3 with the previous keyframe's score as the normalizer; set 1.0 with
    /// ORB-SLAM's normalizer, the lowest score between the query and its covisible
    /// keyframes).
    pub min_normalized_score: f64,
    /// A query whose normalizer is below this is skipped and breaks the consistency
    /// (DLoopDetector's `min_nss_factor`).
    pub min_normalizer: f64,
    /// Entries with `query_id - id < min_gap` (the recent keyframes, and any later id) are
    /// never candidates (DLoopDetector's `dislocal`).
    pub min_gap: u32,
    /// Candidates (sorted by id) whose ids differ by less than this join one island
    /// (DLoopDetector's `max_intragroup_gap`).
    pub max_island_gap: u32,
    /// Islands whose accumulated score is at least this fraction of the best island's are
    /// kept (ORB-SLAM2's 0.75).
    pub island_ratio: f64,
    /// An island is reported once it has continued a group of the previous query this many
    /// times in a row, i.e. from the `consistency + 1`-th consecutive query that finds it
    /// (ORB-SLAM2's `mnCovisibilityConsistencyTh`, DLoopDetector's `k`: both report at the
    /// fourth query with 3).
    pub consistency: usize,
    /// Islands of consecutive queries are consistent when their id ranges overlap or are at
    /// most this far apart (DLoopDetector's `max_distance_between_groups`).
    pub max_group_distance: u32,
}

impl Default for LoopDetectorConfig {
    fn default() -> Self {
        LoopDetectorConfig {
            max_results: 50,
            min_score: 0.01,
            min_normalized_score: 0.3,
            min_normalizer: 0.005,
            min_gap: 20,
            max_island_gap: 3,
            island_ratio: 0.75,
            consistency: 3,
            max_group_distance: 3,
        }
    }
}

impl LoopDetectorConfig {
    /// `Err` naming the first setting out of range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            self.max_results >= 1,
            "bow loop max_results must be at least 1",
        )?;
        check(
            (0.0..=1.0).contains(&self.min_score),
            "bow loop min_score must be in [0, 1]",
        )?;
        check(
            self.min_normalized_score.is_finite() && self.min_normalized_score >= 0.0,
            "bow loop min_normalized_score must be finite and non-negative",
        )?;
        check(
            (0.0..=1.0).contains(&self.min_normalizer),
            "bow loop min_normalizer must be in [0, 1]",
        )?;
        check(self.min_gap >= 1, "bow loop min_gap must be at least 1")?;
        check(
            self.max_island_gap >= 1,
            "bow loop max_island_gap must be at least 1",
        )?;
        check(
            self.island_ratio > 0.0 && self.island_ratio <= 1.0,
            "bow loop island_ratio must be in (0, 1]",
        )?;
        check(
            self.consistency >= 1,
            "bow loop consistency must be at least 1",
        )
    }
}

/// A loop the detector reports; the caller verifies it geometrically before closing it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopCandidate {
    /// The best-scoring keyframe of the reported island.
    pub matched_id: u32,
    /// Its score against the query.
    pub score: f64,
    /// First keyframe id of the island.
    pub first_id: u32,
    /// Last keyframe id of the island.
    pub last_id: u32,
    /// Sum of the scores of the island's candidates.
    pub island_score: f64,
    /// Times in a row the island has continued a group of the previous query (at least the
    /// configured consistency).
    pub consistency: usize,
}

/// An island of candidates with consecutive ids.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Island {
    first: u32,
    last: u32,
    acc: f64,
    best_id: u32,
    best_score: f64,
}

/// An island of the previous query and the number of times in a row it has continued a group
/// of the query before.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Group {
    first: u32,
    last: u32,
    count: usize,
}

/// Bag-of-words loop detection over a keyframe sequence (DLoopDetector's
/// `TemplatedLoopDetector::detectLoop` with ORB-SLAM2's island ratio and consistency).
///
/// For each new keyframe, in this order: the database is queried, the recent keyframes
/// excluded; candidates below `max(min_score, min_normalized_score * normalizer)` are
/// dropped; the rest are grouped into islands of near-consecutive ids, each scored by the sum
/// of its candidates' scores, and the islands within `island_ratio` of the best are kept;
/// each kept island continues a group of the previous query when their id ranges overlap or
/// lie close (`max_group_distance`), and is reported once it has done so `consistency` times
/// in a row. A query without candidates forgets the groups. The detector keeps reporting an
/// island while the queries keep finding it.
///
/// Keyframe ids must increase with time, consecutive keyframes having consecutive ids.
#[derive(Clone, Debug)]
pub struct LoopDetector {
    cfg: LoopDetectorConfig,
    groups: Vec<Group>,
}

impl LoopDetector {
    /// A detector with no history.
    pub fn new(cfg: LoopDetectorConfig) -> Result<LoopDetector, ConfigError> {
        cfg.validate()?;
        Ok(LoopDetector {
            cfg,
            groups: Vec::new(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &LoopDetectorConfig {
        &self.cfg
    }

    /// Forgets the consistency history (after a loop is closed, or the map reset).
    pub fn reset(&mut self) {
        self.groups.clear();
    }

    /// Looks for a loop for keyframe `query_id` with vector `bow` in `db` (which should not
    /// hold the query yet: the caller adds it after detection). `normalizer_score` is the
    /// expected score of a true match: the score against the previous keyframe (DBoW2) or
    /// the lowest score against the covisible keyframes (ORB-SLAM2, with
    /// `min_normalized_score = 1`).
    pub fn detect(
        &mut self,
        db: &Database,
        query_id: u32,
        bow: &BowVector,
        normalizer_score: f64,
    ) -> Option<LoopCandidate> {
        self.detect_excluding(db, query_id, bow, normalizer_score, |_| false)
    }

    /// [`detect`](Self::detect) with further keyframes never candidates (ORB-SLAM2
    /// excludes the query's covisible keyframes).
    pub fn detect_excluding(
        &mut self,
        db: &Database,
        query_id: u32,
        bow: &BowVector,
        normalizer_score: f64,
        exclude: impl Fn(u32) -> bool,
    ) -> Option<LoopCandidate> {
        let cfg = &self.cfg;
        if normalizer_score.is_nan() || normalizer_score < cfg.min_normalizer {
            self.groups.clear();
            return None;
        }
        let threshold = cfg
            .min_score
            .max(cfg.min_normalized_score * normalizer_score);
        let min_gap = cfg.min_gap;
        let mut candidates = db.query(bow, cfg.max_results, |id| {
            query_id.saturating_sub(id) < min_gap || exclude(id)
        });
        candidates.retain(|c| c.1 >= threshold);
        if candidates.is_empty() {
            self.groups.clear();
            return None;
        }
        let islands = self.islands(candidates);
        let mut groups = Vec::with_capacity(islands.len());
        let mut reported = None;
        for island in &islands {
            let count = self
                .groups
                .iter()
                .filter(|g| self.consistent(g, island))
                .map(|g| g.count + 1)
                .max()
                .unwrap_or(0);
            groups.push(Group {
                first: island.first,
                last: island.last,
                count,
            });
            if reported.is_none() && count >= self.cfg.consistency {
                reported = Some(LoopCandidate {
                    matched_id: island.best_id,
                    score: island.best_score,
                    first_id: island.first,
                    last_id: island.last,
                    island_score: island.acc,
                    consistency: count,
                });
            }
        }
        self.groups = groups;
        reported
    }

    /// The kept islands of `candidates` (id, score), best accumulated score first (ties by
    /// first id).
    fn islands(&self, mut candidates: Vec<(u32, f64)>) -> Vec<Island> {
        candidates.sort_by_key(|c| c.0);
        let mut islands: Vec<Island> = Vec::new();
        for (id, s) in candidates {
            match islands.last_mut() {
                Some(isl) if id - isl.last < self.cfg.max_island_gap => {
                    isl.last = id;
                    isl.acc += s;
                    if s > isl.best_score {
                        isl.best_id = id;
                        isl.best_score = s;
                    }
                }
                _ => islands.push(Island {
                    first: id,
                    last: id,
                    acc: s,
                    best_id: id,
                    best_score: s,
                }),
            }
        }
        let best = islands.iter().map(|i| i.acc).fold(0.0, f64::max);
        islands.retain(|i| i.acc >= self.cfg.island_ratio * best);
        islands.sort_by(|a, b| b.acc.total_cmp(&a.acc).then(a.first.cmp(&b.first)));
        islands
    }

    /// Whether an island continues a previous query's group: overlapping id ranges, or at
    /// most `max_group_distance` apart.
    fn consistent(&self, g: &Group, island: &Island) -> bool {
        let gap = if island.last < g.first {
            g.first - island.last
        } else {
            island.first.saturating_sub(g.last)
        };
        gap <= self.cfg.max_group_distance
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_descriptor(rng: &mut ChaCha8Rng) -> Descriptor {
        Descriptor([rng.random(), rng.random(), rng.random(), rng.random()])
    }

    fn bit(d: &Descriptor, i: usize) -> bool {
        (d.0[i / 64] >> (i % 64)) & 1 == 1
    }

    /// Brute-force per-bit majority: bit set when at least half the descriptors have it.
    fn brute_majority(ds: &[Descriptor]) -> Descriptor {
        let mut out = Descriptor::default();
        for i in 0..256 {
            let ones = ds.iter().filter(|d| bit(d, i)).count();
            if 2 * ones >= ds.len() {
                out.0[i / 64] |= 1 << (i % 64);
            }
        }
        out
    }

    /// `d` with each bit flipped with probability `p`.
    fn flip(d: &Descriptor, p: f64, rng: &mut ChaCha8Rng) -> Descriptor {
        let mut out = *d;
        for i in 0..256 {
            if rng.random_bool(p) {
                out.0[i / 64] ^= 1 << (i % 64);
            }
        }
        out
    }

    /// Texture "atoms" shared by every place (real ORB descriptors cluster; uniform random
    /// ones do not).
    const N_ATOMS: usize = 64;
    /// Bits flipped from an atom to a place's own descriptor.
    const VARIANT_FLIP: f64 = 0.2;
    /// Descriptors in a place's pool.
    const POOL: usize = 400;
    /// Share of the pool one view sees (~300 descriptors).
    const VIEW_KEEP: f64 = 0.75;
    /// Bits flipped by viewing noise.
    const VIEW_NOISE: f64 = 0.03;
    /// The revisit drops 30% more of the descriptors...
    const REVISIT_KEEP: f64 = 0.7;
    /// ...and flips 7% of the bits.
    const REVISIT_NOISE: f64 = 0.07;
    const N_PLACES: usize = 21;
    const FRAMES_PER_PLACE: usize = 5;
    const REVISITED: usize = 5;
    const REVISIT_FRAMES: usize = 6;

    fn atoms(rng: &mut ChaCha8Rng) -> Vec<Descriptor> {
        (0..N_ATOMS).map(|_| random_descriptor(rng)).collect()
    }

    /// A place's descriptor pool: variants of random atoms.
    fn place_pool(atoms: &[Descriptor], rng: &mut ChaCha8Rng) -> Vec<Descriptor> {
        (0..POOL)
            .map(|_| flip(&atoms[rng.random_range(0..atoms.len())], VARIANT_FLIP, rng))
            .collect()
    }

    /// One view of a place: each pool descriptor kept with probability `keep`, its bits
    /// flipped with probability `noise`.
    fn view(pool: &[Descriptor], keep: f64, noise: f64, rng: &mut ChaCha8Rng) -> Vec<Descriptor> {
        let kept: Vec<Descriptor> = pool
            .iter()
            .filter(|_| rng.random_bool(keep))
            .copied()
            .collect();
        kept.iter().map(|d| flip(d, noise, rng)).collect()
    }

    /// A keyframe sequence: places 0..N_PLACES, FRAMES_PER_PLACE views each, then
    /// REVISIT_FRAMES noisier views of place REVISITED. With `look_alike = Some((a, b))`
    /// place `b`'s pool is place `a`'s with 15% of its descriptors replaced (rows that look
    /// alike). Keyframe id = index.
    struct Sequence {
        frames: Vec<Vec<Descriptor>>,
        place: Vec<usize>,
        first_pass: usize,
    }

    fn sequence(seed: u64, look_alike: Option<(usize, usize)>) -> Sequence {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let atoms = atoms(&mut rng);
        let mut pools: Vec<Vec<Descriptor>> = (0..N_PLACES)
            .map(|_| place_pool(&atoms, &mut rng))
            .collect();
        if let Some((a, b)) = look_alike {
            let own = place_pool(&atoms, &mut rng);
            pools[b] = pools[a]
                .iter()
                .zip(&own)
                .map(|(x, y)| if rng.random_bool(0.15) { *y } else { *x })
                .collect();
        }
        let mut frames = Vec::new();
        let mut place = Vec::new();
        for (p, pool) in pools.iter().enumerate() {
            for _ in 0..FRAMES_PER_PLACE {
                frames.push(view(pool, VIEW_KEEP, VIEW_NOISE, &mut rng));
                place.push(p);
            }
        }
        let first_pass = frames.len();
        for _ in 0..REVISIT_FRAMES {
            let noisy = view(
                &pools[REVISITED],
                VIEW_KEEP * REVISIT_KEEP,
                VIEW_NOISE,
                &mut rng,
            );
            frames.push(
                noisy
                    .iter()
                    .map(|d| flip(d, REVISIT_NOISE, &mut rng))
                    .collect(),
            );
            place.push(REVISITED);
        }
        Sequence {
            frames,
            place,
            first_pass,
        }
    }

    /// A vocabulary trained on the first pass, as DBoW2's demo trains on its sequence:
    /// synthetic descriptors lack the structure that lets a vocabulary from unrelated images
    /// quantize real ORB descriptors consistently.
    fn sequence_vocabulary(seq: &Sequence) -> Vocabulary {
        let cfg = VocabularyConfig {
            depth: 4,
            ..VocabularyConfig::default()
        };
        Vocabulary::train(&seq.frames[..seq.first_pass], &cfg).unwrap()
    }

    /// The detector over the whole sequence, the previous keyframe's score as the normalizer
    /// (DBoW2), each keyframe added after its query.
    fn run_detector(seq: &Sequence, voc: &Vocabulary) -> Vec<Option<LoopCandidate>> {
        let mut db = Database::new();
        let mut det = LoopDetector::new(LoopDetectorConfig::default()).unwrap();
        let mut prev: Option<BowVector> = None;
        let mut out = Vec::new();
        for (id, frame) in seq.frames.iter().enumerate() {
            let bow = voc.transform(frame);
            let normalizer = prev.as_ref().map_or(0.0, |p| score(&bow, p));
            out.push(det.detect(&db, id as u32, &bow, normalizer));
            db.add(id as u32, bow.clone()).unwrap();
            prev = Some(bow);
        }
        out
    }

    /// Every training descriptor routed down the tree: the descriptors through each node.
    fn routed(voc: &Vocabulary, images: &[Vec<Descriptor>]) -> Vec<Vec<Descriptor>> {
        let mut members = vec![Vec::new(); voc.n_nodes()];
        for d in images.iter().flatten() {
            let mut node = 0usize;
            members[0].push(*d);
            while voc.n_children[node] > 0 {
                let first = voc.first_child[node] as usize;
                let n = voc.n_children[node] as usize;
                let dists: Vec<u32> = (first..first + n)
                    .map(|c| hamming(d, &voc.centers[c]))
                    .collect();
                let min = *dists.iter().min().unwrap();
                node = first + dists.iter().position(|&x| x == min).unwrap();
                members[node].push(*d);
            }
        }
        members
    }

    fn random_images(n: usize, per: usize, seed: u64) -> Vec<Vec<Descriptor>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let atoms = atoms(&mut rng);
        (0..n)
            .map(|_| {
                let pool = place_pool(&atoms, &mut rng);
                pool.into_iter().take(per).collect()
            })
            .collect()
    }

    #[test]
    fn majority_is_the_per_bit_vote() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        // Sizes across the 255-descriptor flush of the byte counters, odd and even.
        for n in [1usize, 2, 3, 4, 7, 254, 255, 256, 510, 511, 600] {
            let ds: Vec<Descriptor> = (0..n).map(|_| random_descriptor(&mut rng)).collect();
            let mut c = BitCounts::new();
            ds.iter().for_each(|d| c.add(d));
            assert_eq!(c.majority(), brute_majority(&ds), "n = {n}");
        }
        // A tie sets the bit (DBoW2's FORB::meanValue).
        let a = Descriptor([0b01, 0, 0, 0]);
        let b = Descriptor([0b10, 0, 0, 0]);
        let mut c = BitCounts::new();
        c.add(&a);
        c.add(&b);
        assert_eq!(c.majority(), Descriptor([0b11, 0, 0, 0]));
    }

    #[test]
    fn trained_centers_are_majorities_of_their_members() {
        let images = random_images(12, 100, 5);
        let cfg = VocabularyConfig {
            branching: 4,
            depth: 4,
            max_iterations: 10_000,
            ..VocabularyConfig::default()
        };
        let voc = Vocabulary::train(&images, &cfg).unwrap();
        let members = routed(&voc, &images);
        // k-medians converged: each node's centre is the majority of the descriptors the
        // tree routes through it (a leaf of the trivial case: that one descriptor).
        for (node, (center, through)) in voc.centers.iter().zip(&members).enumerate().skip(1) {
            assert!(!through.is_empty(), "node {node} unreachable");
            assert_eq!(*center, brute_majority(through), "node {node}");
        }
        // A k-medians node has at most k children, and leaves are at depth <= L.
        assert!(voc.n_children.iter().all(|&n| n as usize <= cfg.branching));
        assert!(voc.depths.iter().all(|&d| d as usize <= cfg.depth));
        assert!(voc.n_words() > 200, "{} words", voc.n_words());
    }

    #[test]
    fn training_is_bit_identical_for_a_seed_whatever_the_threads() {
        let images = random_images(40, 300, 9);
        let cfg = VocabularyConfig {
            depth: 4,
            ..VocabularyConfig::default()
        };
        let train_in = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| Vocabulary::train(&images, &cfg).unwrap())
        };
        let one = train_in(1);
        let three = train_in(3);
        let again = train_in(3);
        assert_eq!(one.to_bytes(), three.to_bytes());
        assert_eq!(three.to_bytes(), again.to_bytes());
        assert_eq!(one, three);
        let other_seed = Vocabulary::train(
            &images,
            &VocabularyConfig {
                seed: cfg.seed + 1,
                ..cfg.clone()
            },
        )
        .unwrap();
        assert_ne!(one.to_bytes(), other_seed.to_bytes());
    }

    #[test]
    fn idf_weights_follow_document_counts() {
        let d = |x: u64| Descriptor([x, 0, 0, 0]);
        let (a, b, c, e) = (d(1), d(2), d(4), d(8));
        // 7 descriptors <= k: one word per distinct descriptor (depth 1).
        let images = vec![vec![a, b], vec![a, c], vec![a, b, e, a]];
        let cfg = VocabularyConfig {
            branching: 8,
            ..VocabularyConfig::default()
        };
        let voc = Vocabulary::train(&images, &cfg).unwrap();
        assert_eq!(voc.n_words(), 4);
        assert_eq!(voc.training_images(), 3);
        let idf = |x: &Descriptor| voc.word_weight(voc.word(x)).unwrap();
        assert_eq!(idf(&a), 0.0); // in every image: a stop word
        assert!((idf(&b) - (3.0f64 / 2.0).ln()).abs() < 1e-15);
        assert!((idf(&c) - 3.0f64.ln()).abs() < 1e-15);
        assert!((idf(&e) - 3.0f64.ln()).abs() < 1e-15);
        // tf-idf, L1: a (weight 0) is skipped; b twice, c once.
        let v = voc.transform(&[a, b, b, c]);
        let (wb, wc) = (2.0 * (1.5f64).ln(), 3.0f64.ln());
        assert_eq!(v.len(), 2);
        assert!((v.get(voc.word(&b)).unwrap() - wb / (wb + wc)).abs() < 1e-15);
        assert!((v.get(voc.word(&c)).unwrap() - wc / (wb + wc)).abs() < 1e-15);
        assert!(voc.transform(&[a, a]).is_empty());
    }

    #[test]
    fn training_rejects_bad_input() {
        let cfg = VocabularyConfig::default();
        assert!(matches!(
            Vocabulary::train(&[], &cfg),
            Err(BowError::EmptyTrainingSet)
        ));
        assert!(matches!(
            Vocabulary::train(&[vec![], vec![]], &cfg),
            Err(BowError::EmptyTrainingSet)
        ));
        let bad = VocabularyConfig {
            branching: 1,
            ..cfg.clone()
        };
        let err = Vocabulary::train(&[vec![Descriptor::default()]], &bad).unwrap_err();
        assert!(err.to_string().contains("branching"), "{err}");
        // Identical descriptors only: one word.
        let same = vec![vec![Descriptor([7, 7, 7, 7]); 50]; 3];
        let voc = Vocabulary::train(&same, &cfg).unwrap();
        assert_eq!(voc.n_words(), 1);
        assert_eq!(voc.n_nodes(), 2);
    }

    #[test]
    fn leaf_centers_map_to_their_leaf() {
        let images = random_images(30, 300, 11);
        let cfg = VocabularyConfig {
            depth: 4,
            ..VocabularyConfig::default()
        };
        let voc = Vocabulary::train(&images, &cfg).unwrap();
        let members = routed(&voc, &images);
        let mut singletons = 0;
        let mut home = 0;
        for w in 0..voc.n_words() as u32 {
            let word = WordId(w);
            let center = voc.word_center(word).unwrap();
            let node = voc.word_node(word).unwrap().0 as usize;
            // A leaf holding one distinct training descriptor has it as its centre, and the
            // descent that assigned it in training brings it back.
            if members[node].iter().all(|d| *d == members[node][0]) {
                singletons += 1;
                assert_eq!(center, members[node][0]);
                assert_eq!(voc.word(&center), word, "word {w}");
            }
            if voc.word(&center) == word {
                home += 1;
            }
        }
        assert!(
            singletons > voc.n_words() / 2,
            "{singletons} singleton leaves"
        );
        // A k-medians leaf centre need not descend to its own leaf, but nearly all do.
        assert!(
            home as f64 >= 0.95 * voc.n_words() as f64,
            "{home} of {} leaf centres map home",
            voc.n_words()
        );
        // Every training descriptor's word is the leaf it was clustered into: transform of a
        // single descriptor is that word alone with weight 1.
        let d = images[3][17];
        let v = voc.transform(&[d]);
        if voc.word_weight(voc.word(&d)).unwrap() > 0.0 {
            assert_eq!(v.iter().collect::<Vec<_>>(), vec![(voc.word(&d), 1.0)]);
        }
    }

    #[test]
    fn bow_vectors_are_normalized_and_scores_are_l1() {
        let images = random_images(30, 300, 13);
        let voc = Vocabulary::train(&images, &VocabularyConfig::default()).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(14);
        let vs: Vec<BowVector> = images
            .iter()
            .map(|img| {
                let noisy: Vec<Descriptor> = img.iter().map(|d| flip(d, 0.03, &mut rng)).collect();
                voc.transform(&noisy)
            })
            .collect();
        for v in &vs {
            let sum: f64 = v.iter().map(|e| e.1).sum();
            assert!((sum - 1.0).abs() < 1e-12, "L1 norm {sum}");
            assert!(v.iter().all(|e| e.1 > 0.0));
            assert!(v.entries.windows(2).all(|w| w[0].0 < w[1].0));
            assert!((score(v, v) - 1.0).abs() < 1e-12);
        }
        // score = 1 - ½‖a - b‖₁, computed independently over the union of words.
        for (a, b) in vs.iter().zip(vs.iter().skip(1)) {
            let mut words: Vec<WordId> = a.iter().chain(b.iter()).map(|e| e.0).collect();
            words.sort();
            words.dedup();
            let l1: f64 = words
                .iter()
                .map(|w| (a.get(*w).unwrap_or(0.0) - b.get(*w).unwrap_or(0.0)).abs())
                .sum();
            let s = score(a, b);
            assert!((s - (1.0 - 0.5 * l1)).abs() < 1e-12);
            assert!((0.0..=1.0).contains(&s));
            assert_eq!(s, score(b, a));
        }
        let x = BowVector::from_weights(vec![(WordId(1), 2.0), (WordId(5), 1.0), (WordId(1), 1.0)]);
        let y = BowVector::from_weights(vec![(WordId(2), 1.0), (WordId(7), 3.0)]);
        assert_eq!(x.get(WordId(1)), Some(0.75));
        assert_eq!(score(&x, &y), 0.0);
        assert_eq!(score(&x, &BowVector::default()), 0.0);
        assert!(BowVector::from_weights(vec![(WordId(3), 0.0)]).is_empty());
    }

    #[test]
    fn feature_vector_files_features_under_their_ancestors() {
        let images = random_images(20, 300, 15);
        let cfg = VocabularyConfig {
            depth: 4,
            ..VocabularyConfig::default()
        };
        let voc = Vocabulary::train(&images, &cfg).unwrap();
        let img = &images[2];
        for levels_up in [0usize, 1, 2, 4, 7] {
            let (bow, fv) = voc.transform_with_features(img, levels_up);
            assert_eq!(bow, voc.transform(img));
            let target = cfg.depth.saturating_sub(levels_up) as u32;
            let mut seen = Vec::new();
            for (node, features) in fv.iter() {
                assert!(features.windows(2).all(|w| w[0] < w[1]));
                for &f in features {
                    seen.push(f);
                    let leaf = voc.word_node(voc.word(&img[f])).unwrap().0;
                    // Walk up from the leaf to the expected depth.
                    let mut n = leaf;
                    while voc.depths[n as usize] > target {
                        n = voc.parents[n as usize];
                    }
                    assert_eq!(NodeId(n), node, "feature {f}, levels_up {levels_up}");
                }
            }
            seen.sort_unstable();
            let counted: Vec<usize> = (0..img.len())
                .filter(|&f| voc.word_weight(voc.word(&img[f])).unwrap() > 0.0)
                .collect();
            assert_eq!(seen, counted);
            if levels_up >= cfg.depth {
                assert_eq!(fv.len(), 1);
                assert!(fv.get(NodeId(0)).is_some());
            }
        }
        let (_, a) = voc.transform_with_features(&images[0], 2);
        let (_, b) = voc.transform_with_features(&images[0], 2);
        assert_eq!(a.common(&b).count(), a.len());
    }

    #[test]
    fn write_read_round_trip_and_corruption() {
        let images = random_images(20, 200, 17);
        let voc = Vocabulary::train(&images, &VocabularyConfig::default()).unwrap();
        let mut file = Vec::new();
        voc.write(&mut file).unwrap();
        let back = Vocabulary::read(file.as_slice()).unwrap();
        assert_eq!(back, voc);
        assert_eq!(back.to_bytes(), file);
        assert_eq!(back.transform(&images[1]), voc.transform(&images[1]));

        let err = |bytes: &[u8]| Vocabulary::from_bytes(bytes).unwrap_err().to_string();
        let mut bad = file.clone();
        bad[..6].copy_from_slice(b"DBOW2!");
        assert_eq!(
            err(&bad),
            "vocabulary file: expected magic VBVOC1, found \"DBOW2!\""
        );
        bad[..6].copy_from_slice(b"VBVOC2");
        assert!(
            err(&bad).contains("expected format version 1"),
            "{}",
            err(&bad)
        );
        assert!(err(&[]).contains("expected magic VBVOC1, found \"\""));
        let mut flipped = file.clone();
        flipped[500] ^= 0x10;
        assert!(err(&flipped).contains("file corrupted or truncated"));
        assert!(err(&file[..file.len() - 100]).contains("checksum"));
        assert!(err(&file[..20]).contains("at least 30 bytes"));
        // A consistent checksum over a broken tree is still caught by the structure checks.
        let mut body = file[..file.len() - 8].to_vec();
        body[6 + 16..6 + 20].copy_from_slice(&7u32.to_le_bytes()); // node 1's parent
        let sum = fnv1a(&body[6..]);
        body.extend_from_slice(&sum.to_le_bytes());
        assert!(
            err(&body).contains("parent to be an earlier internal node"),
            "{}",
            err(&body)
        );
    }

    #[test]
    fn database_query_ranks_by_score() {
        let images = random_images(30, 300, 19);
        let voc = Vocabulary::train(&images, &VocabularyConfig::default()).unwrap();
        let mut db = Database::new();
        // Ids out of order, and two entries with the same vector (a tie).
        let ids: Vec<u32> = (0..images.len() as u32).map(|i| 1000 - 3 * i).collect();
        for (id, img) in ids.iter().zip(&images) {
            db.add(*id, voc.transform(img)).unwrap();
        }
        db.add(5, voc.transform(&images[4])).unwrap();
        assert!(matches!(
            db.add(5, BowVector::default()),
            Err(BowError::DuplicateEntry(5))
        ));
        assert_eq!(db.len(), images.len() + 1);
        let q = voc.transform(&images[4]);
        let all = db.query(&q, usize::MAX, |_| false);
        // Scores are score() bit for bit, sorted, ties by id.
        for (id, s) in &all {
            assert_eq!(*s, score(&q, db.get(*id).unwrap()));
        }
        assert!(
            all.windows(2)
                .all(|w| w[0].1 > w[1].1 || (w[0].1 == w[1].1 && w[0].0 < w[1].0))
        );
        assert_eq!(all[0].0, 5);
        assert_eq!(all[1].0, ids[4]);
        assert_eq!(all[0].1, all[1].1);
        // Every entry with a common word, and only those.
        let sharing = db
            .ids()
            .iter()
            .filter(|id| score(&q, db.get(**id).unwrap()) > 0.0)
            .count();
        assert_eq!(all.len(), sharing);
        let top3 = db.query(&q, 3, |_| false);
        assert_eq!(top3, all[..3].to_vec());
        let excluded = db.query(&q, usize::MAX, |id| id == 5);
        assert_eq!(excluded, all[1..].to_vec());
        assert!(db.query(&BowVector::default(), 10, |_| false).is_empty());
    }

    #[test]
    fn revisited_place_is_retrieved_and_detected_after_consistency() {
        let seq = sequence(21, None);
        let voc = sequence_vocabulary(&seq);
        // The database retrieves place 5 for the first revisit frame.
        let mut db = Database::new();
        for (id, frame) in seq.frames[..seq.first_pass].iter().enumerate() {
            db.add(id as u32, voc.transform(frame)).unwrap();
        }
        for r in seq.first_pass..seq.frames.len() {
            let q = voc.transform(&seq.frames[r]);
            let best = db.query(&q, 5, |_| false);
            assert_eq!(
                seq.place[best[0].0 as usize], REVISITED,
                "frame {r}: {best:?}"
            );
        }
        // The detector: silent over the first pass (all places distinct), reports the
        // revisit once it has been consistent `consistency` times (from the 4th frame).
        let found = run_detector(&seq, &voc);
        let consistency = LoopDetectorConfig::default().consistency;
        for (id, f) in found.iter().enumerate() {
            let revisit_frame = id.checked_sub(seq.first_pass);
            match revisit_frame {
                Some(k) if k >= consistency => {
                    let c = f.unwrap_or_else(|| panic!("revisit frame {k} not reported"));
                    assert_eq!(seq.place[c.matched_id as usize], REVISITED, "{c:?}");
                    assert!(c.consistency >= consistency);
                    assert!(c.first_id <= c.matched_id && c.matched_id <= c.last_id);
                }
                _ => assert!(f.is_none(), "keyframe {id}: false report {f:?}"),
            }
        }
    }

    #[test]
    fn look_alike_rows_give_a_false_loop() {
        // Place 12 shares 85% of place 4's descriptors: two vine rows that look alike.
        let (a, b) = (4, 12);
        let seq = sequence(23, Some((a, b)));
        let voc = sequence_vocabulary(&seq);
        let found = run_detector(&seq, &voc);
        let false_loops: Vec<(usize, LoopCandidate)> = found[..seq.first_pass]
            .iter()
            .enumerate()
            .filter_map(|(id, f)| f.map(|c| (id, c)))
            .collect();
        // The look-alike rows are confused: a loop from row b to row a. (Other false loops
        // may follow, when a low-threshold query's wide island continues that group.)
        assert!(
            false_loops
                .iter()
                .any(|(id, c)| seq.place[*id] == b && seq.place[c.matched_id as usize] == a),
            "the look-alike rows were not confused: {false_loops:?}"
        );
        assert!(
            false_loops.iter().all(|(id, _)| seq.place[*id] >= b),
            "false loops before the look-alike row: {false_loops:?}"
        );
    }

    #[test]
    fn loop_detector_config_checks_and_serde() {
        assert!(LoopDetector::new(LoopDetectorConfig::default()).is_ok());
        for bad in [
            LoopDetectorConfig {
                consistency: 0,
                ..LoopDetectorConfig::default()
            },
            LoopDetectorConfig {
                island_ratio: 1.5,
                ..LoopDetectorConfig::default()
            },
            LoopDetectorConfig {
                min_gap: 0,
                ..LoopDetectorConfig::default()
            },
            LoopDetectorConfig {
                min_score: f64::NAN,
                ..LoopDetectorConfig::default()
            },
        ] {
            assert!(LoopDetector::new(bad).is_err());
        }
        let cfg: LoopDetectorConfig = toml::from_str("consistency = 4\nmin_gap = 30").unwrap();
        assert_eq!(cfg.consistency, 4);
        assert_eq!(cfg.min_gap, 30);
        assert_eq!(cfg.island_ratio, 0.75);
        assert!(toml::from_str::<LoopDetectorConfig>("consistensy = 4").is_err());
        let voc: VocabularyConfig = toml::from_str("branching = 8").unwrap();
        assert_eq!(voc.depth, DEFAULT_DEPTH);
        assert!(toml::from_str::<VocabularyConfig>("levels = 4").is_err());
    }

    /// Timings for the report: `cargo test --release --lib slam::bow::tests::timing --
    /// --ignored --nocapture`.
    #[test]
    #[ignore]
    fn timing() {
        let mut rng = ChaCha8Rng::seed_from_u64(29);
        let atoms = atoms(&mut rng);
        let structured: Vec<Vec<Descriptor>> = (0..200)
            .map(|_| {
                let mut img = place_pool(&atoms, &mut rng);
                img.extend(place_pool(&atoms, &mut rng));
                img.extend(place_pool(&atoms, &mut rng));
                img.truncate(1000);
                img
            })
            .collect();
        let uniform: Vec<Vec<Descriptor>> = (0..200)
            .map(|_| (0..1000).map(|_| random_descriptor(&mut rng)).collect())
            .collect();
        println!("threads: {}", rayon::current_num_threads());
        for (name, images) in [("structured", &structured), ("uniform", &uniform)] {
            for depth in [4, 5] {
                let cfg = VocabularyConfig {
                    depth,
                    ..VocabularyConfig::default()
                };
                let t = std::time::Instant::now();
                let voc = Vocabulary::train(images, &cfg).unwrap();
                let train = t.elapsed();
                let t = std::time::Instant::now();
                let bows: Vec<BowVector> = images.iter().map(|i| voc.transform(i)).collect();
                let transform = t.elapsed() / images.len() as u32;
                let mut db = Database::new();
                for i in 0..1000u32 {
                    db.add(i, bows[i as usize % bows.len()].clone()).unwrap();
                }
                let t = std::time::Instant::now();
                for b in &bows[..50] {
                    std::hint::black_box(db.query(b, 50, |_| false));
                }
                let query = t.elapsed() / 50;
                let t = std::time::Instant::now();
                let bytes = voc.to_bytes();
                let back = Vocabulary::from_bytes(&bytes).unwrap();
                let io = t.elapsed();
                assert_eq!(back, voc);
                println!(
                    "{name} 200x1000, k=10 L={depth}: train {train:?} ({} words, {} nodes); \
                     transform {transform:?}/image; query (1000 entries) {query:?}; \
                     write+read {io:?} ({} bytes)",
                    voc.n_words(),
                    voc.n_nodes(),
                    bytes.len()
                );
            }
        }
    }
}
