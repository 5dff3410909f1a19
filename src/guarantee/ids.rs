//! An index from ids (base faces, dense vertices) to their places in a list: the checks ask
//! "where is face f in this neighbourhood" and "what is dense vertex v's map in this candidate"
//! hundreds of millions of times a run, so a binary search (seven to twelve dependent loads)
//! became an open-addressed table (mostly one).
//!
//! ```text
//!   ids:   [ 907, 13, 4411, 20 ]          slots (a power of two, at least twice the ids):
//!   slot of id = (id · φ·2⁶⁴) >> 32 & mask   [ ·, 2, ·, 0, ·, ·, 3, 1 ]   (· = EMPTY)
//!   a taken slot: the next one (linear probing); a slot holds the id's place in `ids`
//! ```
//!
//! And the ids a list names, sorted and each once ([`sorted_unique`]): a candidate's dense
//! triangles are the triangles around its dense vertices, each named by all three corners;
//! collect-sort-dedup sorted every name (with the other lists it serves, a few per cent of a run's
//! CPU on the shipped sample under `perf`, much of it in the serial pick).

/// A free slot.
const EMPTY: u32 = u32::MAX;

/// Place of each id of a list, built once, read many times. It stores places only: the list
/// itself is handed to [`IdIndex::get`], which compares the ids there.
#[derive(Clone, Debug, Default)]
pub struct IdIndex {
    slots: Vec<u32>,
    /// How many ids it was built from (a list that grew since is searched linearly).
    built_from: usize,
}

/// The first slot of `id` in a table of `mask + 1` slots: Fibonacci hashing (the ids of a
/// neighbourhood are clustered; the multiply spreads them).
#[inline]
fn first_slot(id: u32, mask: usize) -> usize {
    ((id as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32) as usize & mask
}

impl IdIndex {
    /// Indexes `ids`; of a repeated id, the first place is kept (as a linear search finds it).
    pub fn build(&mut self, ids: &[u32]) {
        let size = (2 * ids.len()).next_power_of_two().max(16);
        self.slots.clear();
        self.slots.resize(size, EMPTY);
        let mask = size - 1;
        for (i, &id) in ids.iter().enumerate() {
            let mut k = first_slot(id, mask);
            loop {
                let e = self.slots[k];
                if e == EMPTY {
                    self.slots[k] = i as u32;
                    break;
                }
                if ids[e as usize] == id {
                    break;
                }
                k = (k + 1) & mask;
            }
        }
        self.built_from = ids.len();
    }

    /// Forgets every id.
    pub fn clear(&mut self) {
        self.slots.clear();
        self.built_from = 0;
    }

    /// The first place of `id` in `ids` (the list it was built from, or that list grown since).
    #[inline]
    pub fn get(&self, ids: &[u32], id: u32) -> Option<usize> {
        if self.slots.is_empty() || self.built_from != ids.len() {
            return ids.iter().position(|&f| f == id);
        }
        let mask = self.slots.len() - 1;
        let mut k = first_slot(id, mask);
        loop {
            let e = self.slots[k];
            if e == EMPTY {
                return None;
            }
            if ids[e as usize] == id {
                return Some(e as usize);
            }
            k = (k + 1) & mask;
        }
    }
}

thread_local! {
    /// Ids marked, one bit each. Every bit set is cleared again before [`sorted_unique`]
    /// returns, so a thread's set starts empty each time and only grows (to the largest id it
    /// saw / 8 bytes: 250 kB for a 2M-triangle scan).
    static BITS: std::cell::RefCell<Vec<u64>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// When the marked ids span at most this many 64-bit words per id kept, reading the words in
/// order beats sorting the ids. Why: a word costs about one step; sorting costs log2(n)
/// compares and moves per id (measured on the shipped sample's lists: 10^3–10^4 ids).
const SCAN_WORDS_PER_ID: usize = 4;

/// `out` ← the ids `ids` yields, ascending, each once: what collect, `sort_unstable` and
/// `dedup` give, without sorting the repeats. Marks each id in a bit set (a repeat is dropped
/// there), then reads the ids back in order from the marked words when they are few enough
/// ([`SCAN_WORDS_PER_ID`]), else sorts the kept ids and clears their bits.
pub fn sorted_unique(ids: impl IntoIterator<Item = u32>, out: &mut Vec<u32>) {
    out.clear();
    BITS.with(|b| {
        let words = &mut *b.borrow_mut();
        let (mut lo, mut hi) = (usize::MAX, 0);
        for id in ids {
            let w = (id >> 6) as usize;
            if w >= words.len() {
                words.resize(w + 1, 0);
            }
            let bit = 1u64 << (id & 63);
            if words[w] & bit == 0 {
                words[w] |= bit;
                out.push(id);
                lo = lo.min(w);
                hi = hi.max(w);
            }
        }
        if out.is_empty() {
            return;
        }
        if hi - lo < SCAN_WORDS_PER_ID * out.len() {
            out.clear();
            for (w, word) in words[lo..=hi].iter_mut().enumerate() {
                let mut bits = std::mem::take(word);
                while bits != 0 {
                    out.push((((lo + w) as u32) << 6) | bits.trailing_zeros());
                    bits &= bits - 1;
                }
            }
        } else {
            out.sort_unstable();
            for &id in out.iter() {
                words[(id >> 6) as usize] = 0;
            }
        }
    });
}

/// The ids of two ascending lists, ascending (an id in both, once).
pub fn merge_sorted(a: &[u32], b: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let (x, y) = (a[i], b[j]);
        out.push(x.min(y));
        i += usize::from(x <= y);
        j += usize::from(y <= x);
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

#[cfg(test)]
mod tests {
    use super::{merge_sorted, sorted_unique, IdIndex};

    #[test]
    fn sorted_unique_is_collect_sort_dedup() {
        // Clustered ids with repeats (read back from the words), spread ids (sorted), the
        // empty list, and ids on word edges; each result as sort + dedup gives it, and the set
        // left empty (a second call with other ids is not disturbed by the first).
        let clustered: Vec<u32> = (0..3000u32).map(|i| 5000 + (i * 7) % 1000).collect();
        let spread: Vec<u32> = (0..500u32).map(|i| i.wrapping_mul(2_654_435_761) >> 12).chain([3, 3, 64, 63, 128]).collect();
        let edges = vec![63u32, 64, 0, 127, 128, 64, 0];
        let mut out = Vec::new();
        for ids in [&clustered, &spread, &Vec::new(), &edges, &clustered] {
            let mut want = ids.clone();
            want.sort_unstable();
            want.dedup();
            sorted_unique(ids.iter().copied(), &mut out);
            assert_eq!(out, want);
        }
        assert_eq!(merge_sorted(&[1, 4, 9], &[0, 4, 5, 12]), vec![0, 1, 4, 5, 9, 12]);
        assert_eq!(merge_sorted(&[], &[2]), vec![2]);
    }

    #[test]
    fn the_index_finds_what_a_linear_search_finds() {
        // Ids clustered and spread, some repeated (the first place answers), looked up before
        // and after `build` and after the list grew (then searched linearly).
        let mut ids: Vec<u32> = (0..300u32).map(|i| if i % 3 == 0 { i / 3 } else { i.wrapping_mul(2_654_435_761) >> 8 }).collect();
        ids.push(ids[5]);
        let probe: Vec<u32> = ids.iter().copied().chain([1_000_000, 7_777, u32::MAX - 1]).collect();
        let linear: Vec<Option<usize>> = probe.iter().map(|&f| ids.iter().position(|&g| g == f)).collect();
        let mut index = IdIndex::default();
        assert_eq!(probe.iter().map(|&f| index.get(&ids, f)).collect::<Vec<_>>(), linear);
        index.build(&ids);
        assert_eq!(probe.iter().map(|&f| index.get(&ids, f)).collect::<Vec<_>>(), linear);
        ids.push(4_242_424);
        assert_eq!(index.get(&ids, 4_242_424), Some(301));
        index.clear();
        assert_eq!(index.get(&ids, ids[7]), Some(7));
    }
}
