// Cell insertion, shared by the passes that add cells to the table (`raster`, `fill`): they
// bind the counters, the table, the cell list and the bitmap read-write, with atomics where
// invocations race.

@group(0) @binding(2) var<storage, read_write> counters: array<atomic<u32>>;
@group(0) @binding(3) var<storage, read_write> table: array<atomic<u32>>;
@group(0) @binding(7) var<storage, read_write> list: array<u32>;
@group(0) @binding(8) var<storage, read_write> bitmap: array<atomic<u32>>;

// The global slot of cell `key` (packed local index) in job `j`'s table, inserting it when
// missing (linear probing); -1 when the table is full. The invocation that inserts a cell
// appends its slot to the job's cell list, so the passes after `raster` run over the occupied
// cells only, not over the whole table, and sets the cell's bit in the job's bitmap, from which
// `scan` and `place` derive each cell's rank in (k, j, i) order. A list longer than
// `job.out_cap` is an overflow: the host sees the count and re-runs the job; cells past the
// room get no bit, so a job never has more bits than room. Slots and list order depend on
// scheduling; the sums and the bitmap do not. `filled`: count the cell as a fill (counter 1).
fn find_or_insert(j: u32, job: Job, key: u32, filled: bool) -> i32 {
    let key1 = key + 1u;
    var h = hash32(key) & job.table_mask;
    for (var probe = 0u; probe <= job.table_mask; probe++) {
        let s = job.slot_start + h;
        let w = slot_word(s);
        loop {
            let cur = atomicLoad(&table[w]);
            if cur == key1 {
                return i32(s);
            }
            if cur != 0u {
                break;
            }
            let r = atomicCompareExchangeWeak(&table[w], 0u, key1);
            if r.exchanged {
                let idx = atomicAdd(&counters[counter_word(j, C_OUT)], 1u);
                if idx < job.out_cap {
                    list[job.out_start + idx] = s;
                    let row = key / job.nx;
                    let i = key - row * job.nx;
                    atomicOr(&bitmap[job.bit_start + row * job.row_words + i / 32u], 1u << (i % 32u));
                }
                if filled {
                    atomicAdd(&counters[counter_word(j, C_FILLED)], 1u);
                }
                return i32(s);
            }
            if r.old_value == key1 {
                return i32(s);
            }
            if r.old_value != 0u {
                break;
            }
        }
        h = (h + 1u) & job.table_mask;
    }
    return -1;
}

// The global slot of cell `key` in the job's table, -1 when absent (lookup only).
fn find(job: Job, key: u32) -> i32 {
    let key1 = key + 1u;
    var h = hash32(key) & job.table_mask;
    for (var probe = 0u; probe <= job.table_mask; probe++) {
        let s = job.slot_start + h;
        let cur = atomicLoad(&table[slot_word(s)]);
        if cur == key1 {
            return i32(s);
        }
        if cur == 0u {
            return -1;
        }
        h = (h + 1u) & job.table_mask;
    }
    return -1;
}

// Adds one contribution of view `axis` to the count word at `w`; false when the field was full.
fn add_count(w: u32, axis: u32) -> bool {
    let shift = axis * COUNT_BITS;
    let old = atomicAdd(&table[w], 1u << shift);
    return ((old >> shift) & COUNT_FIELD) != COUNT_FIELD;
}
