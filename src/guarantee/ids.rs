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

#[cfg(test)]
mod tests {
    use super::IdIndex;

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
