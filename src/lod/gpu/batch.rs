//! Batches (the module doc's *Batching and memory*): packing prepared jobs into batches within
//! the budget and the binding limits, recording and submitting a batch's passes, reading it back,
//! and the pooled buffers kept from batch to batch.

use std::sync::atomic::AtomicU64;
use std::sync::mpsc;
use std::time::Instant;

use rayon::prelude::*;
use wgpu::util::DeviceExt;

use super::BatchReport;
use super::prepare::{MeshPrep, check, convert};
use super::{
    BATCH_OVERHEAD, BINDINGS, COLUMN_BYTES, COLUMNS, COUNTER_WORDS, Decoded, FILL, GpuBaker, GpuError,
    GpuJob, GpuLevel, GpuParams, InFlight, JobOutput, LEVEL_STRIDE, LIST_BYTES, LevelJob, MAX_GROUPS_X,
    N_POOLED, P_BITMAP, P_COLUMNS, P_COUNTERS, P_LIST, P_OUT, P_SCAN, P_STAGING, P_TABLE, P_TRIS, P_VERTS,
    PLACE, POINT_BYTES, POOL_SETS, POOLED, Prepared, RASTER, SCAN, SCAN_ADD, SCAN_BLOCK, SCAN_ROWS,
    SLOT_BYTES, WORKGROUP, busy_s, timed,
};

/// Running sizes of a batch being packed, in items of each buffer.
#[derive(Default, Clone, Copy)]
struct Sizes {
    bytes: u64,
    slots: u64,
    out: u64,
    cols: u64,
    verts: u64,
    tris: u64,
    bits: u64,
    scan: u64,
}

impl GpuBaker {
    /// Whether a job fits a batch of its own: budget and binding limits.
    pub(super) fn fits_alone(&self, p: &Prepared, meshes: &[MeshPrep], fill: bool) -> bool {
        let mut s = Sizes { bytes: BATCH_OVERHEAD, ..Sizes::default() };
        self.add(&mut s, p, &meshes[p.mesh], true, fill)
    }

    /// Adds `p` to `s` (its mesh too when `new_mesh`); false when the result is over a limit.
    fn add(&self, s: &mut Sizes, p: &Prepared, m: &MeshPrep, new_mesh: bool, fill: bool) -> bool {
        let v = m.vertices;
        s.bytes += p.bytes(v, fill) + if new_mesh { m.bytes() } else { 0 };
        s.slots += p.table_slots;
        s.out += p.out_cap;
        s.cols += p.columns(fill);
        s.verts += v;
        s.bits += p.rows() * p.row_words();
        s.scan += p.scan_words();
        if new_mesh {
            s.tris += m.tris.len() as u64 / 6;
        }
        let b = self.max_binding;
        let limit_items = u64::from(u32::MAX / 2);
        s.bytes <= self.budget
            && s.slots * SLOT_BYTES <= b
            && s.out * POINT_BYTES <= b
            && s.cols * COLUMN_BYTES <= b
            && s.verts * 12 <= b
            && s.tris * 24 <= self.max_buffer
            && s.tris <= limit_items
            && s.bits * 4 <= b
            && s.scan * 4 <= b
            && s.slots.max(s.cols).max(s.bits).max(s.scan).max(s.verts * 3).max(s.out * 8) <= limit_items
    }

    /// Takes jobs from the front of `queue` while the batch stays within the budget, the
    /// binding limits and 32-bit item counts. A mesh's levels are adjacent in the queue, so
    /// they mostly share a batch and the mesh's upload.
    pub(super) fn take_batch(
        &self,
        queue: &mut std::collections::VecDeque<Prepared>,
        meshes: &[MeshPrep],
        fill: bool,
    ) -> Vec<Prepared> {
        let mut batch: Vec<Prepared> = Vec::new();
        let mut s = Sizes { bytes: BATCH_OVERHEAD, ..Sizes::default() };
        while let Some(p) = queue.front() {
            let mut next = s;
            let new_mesh = !batch.iter().any(|q| q.mesh == p.mesh);
            if !self.add(&mut next, p, &meshes[p.mesh], new_mesh, fill) && !batch.is_empty() {
                break;
            }
            s = next;
            if let Some(p) = queue.pop_front() {
                batch.push(p);
            }
        }
        batch
    }

    /// Uploads a batch (each mesh once), records the passes and the counters' read-back copy,
    /// and submits.
    pub(super) fn submit(
        &self,
        batch: Vec<Prepared>,
        meshes: &[MeshPrep],
        fill: bool,
        report: &mut BatchReport,
    ) -> Result<InFlight, GpuError> {
        let t = Instant::now();
        // Meshes of the batch, their triangles uploaded once each: (mesh, first triangle).
        let mut placed: Vec<(usize, u32)> = Vec::new();
        let mut mesh_tris = 0u64;
        let mut gjobs = Vec::with_capacity(batch.len());
        let (mut raster, mut slots, mut out, mut cols, mut verts, mut rows, mut bits) =
            (0u64, 0u64, 0u64, 0u64, 0u64, 0u64, 0u64);
        for p in &batch {
            let m = &meshes[p.mesh];
            let tri0 = if let Some(&(_, t)) = placed.iter().find(|e| e.0 == p.mesh) {
                t
            } else {
                placed.push((p.mesh, mesh_tris as u32));
                mesh_tris += m.tris.len() as u64 / 6;
                mesh_tris as u32 - (m.tris.len() / 6) as u32
            };
            let tri_count = m.tris.len() as u64 / 6;
            gjobs.push(GpuJob {
                tri_start: tri0,
                tri_count: tri_count as u32,
                vert_start: verts as u32,
                raster_start: raster as u32,
                nx: p.dims[0],
                ny: p.dims[1],
                nz: p.dims[2],
                slot_start: slots as u32,
                table_mask: (p.table_slots - 1) as u32,
                out_start: out as u32,
                out_cap: p.out_cap as u32,
                col_start: cols as u32,
                fill: u32::from(fill),
                row_start: rows as u32,
                bit_start: bits as u32,
                row_words: p.row_words() as u32,
            });
            raster += tri_count * 3;
            slots += p.table_slots;
            out += p.out_cap;
            cols += p.columns(fill);
            verts += m.vertices;
            rows += p.rows();
            bits += p.rows() * p.row_words();
        }
        // Scan levels: level 0 the rows, each next one the block totals of the one below, up
        // to a single value.
        let mut level_off = vec![0u64];
        let mut level_len = vec![rows];
        while let Some(&n) = level_len.last()
            && n > 1
        {
            level_off.push(level_off[level_off.len() - 1] + n);
            level_len.push(n.div_ceil(SCAN_BLOCK));
        }
        let scan_words = level_off[level_off.len() - 1] + 1;
        let top = level_len.len() - 1;
        let mut levels: Vec<GpuLevel> = Vec::new();
        // (pipeline, level entry, items)
        let mut scan_runs: Vec<(usize, usize, u64)> = Vec::new();
        let level = |l: usize| GpuLevel {
            src: level_off[l] as u32,
            count: level_len[l] as u32,
            dst: level_off[(l + 1).min(top)] as u32,
            pad: 0,
        };
        if top == 0 {
            // One row in all: its prefix is 0 (the block scan writes it; its total goes to a
            // word past the prefix).
            levels.push(GpuLevel { src: 0, count: 1, dst: 1, pad: 0 });
            scan_runs.push((SCAN_ROWS, 0, 1));
        } else {
            levels.push(level(0));
            scan_runs.push((SCAN_ROWS, 0, rows));
            for l in 1..top {
                let lv = level(l);
                levels.push(lv);
                scan_runs.push((SCAN, levels.len() - 1, u64::from(lv.count)));
            }
            for l in (0..top.saturating_sub(1)).rev() {
                let lv = level(l);
                levels.push(lv);
                scan_runs.push((SCAN_ADD, levels.len() - 1, u64::from(lv.count)));
            }
        }
        let scan_words = scan_words.max(2);
        // The raster's triangle windows: the batch's triangles in runs that fit the adapter's
        // largest storage binding, at offsets aligned for binding (768 bytes = 32 triangles is
        // a multiple of every offset alignment WebGPU allows); usually one window.
        let window_tris = (self.tri_window_bytes / 768 * 32).max(32);
        let windows: Vec<(u64, u64, usize)> = (0..mesh_tris.div_ceil(window_tris).max(1))
            .map(|w| {
                let base = w * window_tris;
                let count = window_tris.min(mesh_tris - base.min(mesh_tris));
                levels.push(GpuLevel { src: base as u32, count: count as u32, dst: 0, pad: 0 });
                (base, count, levels.len() - 1)
            })
            .collect();
        let params = GpuParams {
            n_jobs: gjobs.len() as u32,
            raster_items: raster as u32,
            slots: slots as u32,
            col_items: cols as u32,
            out_items: out as u32,
            rows: rows as u32,
            pad: [0; 2],
        };
        let mut level_bytes = vec![0u8; levels.len() * LEVEL_STRIDE as usize];
        for (n, l) in levels.iter().enumerate() {
            let o = n * LEVEL_STRIDE as usize;
            level_bytes[o..o + std::mem::size_of::<GpuLevel>()].copy_from_slice(bytemuck::bytes_of(l));
        }
        let d = &self.device;
        let scope = d.push_error_scope(wgpu::ErrorFilter::Validation);
        let init = |label: &str, contents: &[u8], usage: wgpu::BufferUsages| {
            d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
        };
        let counters_bytes = (gjobs.len() * COUNTER_WORDS * 4) as u64;
        let b_params = init("params", bytemuck::bytes_of(&params), wgpu::BufferUsages::UNIFORM);
        let b_jobs = init("jobs", bytemuck::cast_slice(&gjobs), wgpu::BufferUsages::STORAGE);
        let b_levels = init("levels", &level_bytes, wgpu::BufferUsages::UNIFORM);
        // Sizes the batch uses in each pooled buffer (bindings may not be empty).
        let used: [u64; N_POOLED] = [
            mesh_tris * 24,
            verts * 12,
            counters_bytes,
            slots * SLOT_BYTES,
            cols * COLUMN_BYTES,
            out * LIST_BYTES,
            bits * 4,
            scan_words * 4,
            out * POINT_BYTES,
            counters_bytes + out * POINT_BYTES,
        ]
        .map(|b| b.max(16));
        let other = b_params.size() + b_jobs.size() + b_levels.size();
        let (pooled, reused) = self.take_buffers(used, other);
        let mut uploaded = other;
        for &(m, t0) in &placed {
            let m = &meshes[m];
            self.queue.write_buffer(&pooled[P_TRIS], u64::from(t0) * 24, bytemuck::cast_slice(&m.tris));
            uploaded += m.bytes();
        }
        for (p, g) in batch.iter().zip(&gjobs) {
            if !p.verts.is_empty() {
                self.queue.write_buffer(
                    &pooled[P_VERTS],
                    u64::from(g.vert_start) * 12,
                    bytemuck::cast_slice(&p.verts),
                );
                uploaded += p.verts.len() as u64 * 4;
            }
        }
        let bytes = other + pooled.iter().map(wgpu::Buffer::size).sum::<u64>();
        let part = |n: usize| {
            wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &pooled[n],
                offset: 0,
                size: std::num::NonZeroU64::new(used[n]),
            })
        };
        // Binding order (`common.wgsl`).
        let resources = [
            b_params.as_entire_binding(),
            b_jobs.as_entire_binding(),
            part(P_COUNTERS),
            part(P_TABLE),
            part(P_COLUMNS),
            part(P_VERTS),
            part(P_TRIS),
            part(P_LIST),
            part(P_BITMAP),
            part(P_SCAN),
            part(P_OUT),
            wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &b_levels,
                offset: 0,
                size: std::num::NonZeroU64::new(std::mem::size_of::<GpuLevel>() as u64),
            }),
        ];
        let group = |n: usize, tris: Option<(u64, u64)>| {
            let entries: Vec<wgpu::BindGroupEntry<'_>> = BINDINGS[n]
                .iter()
                .map(|&(binding, _)| wgpu::BindGroupEntry {
                    binding,
                    resource: match tris.or(Some((windows[0].0, windows[0].1))) {
                        Some((base, count)) if binding as usize == 6 => {
                            wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                                buffer: &pooled[P_TRIS],
                                offset: base * 24,
                                size: std::num::NonZeroU64::new((count * 24).max(16)),
                            })
                        }
                        _ => resources[binding as usize].clone(),
                    },
                })
                .collect();
            d.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("lod::gpu batch"),
                layout: &self.layouts[n],
                entries: &entries,
            })
        };
        let groups: Vec<wgpu::BindGroup> = (0..BINDINGS.len()).map(|n| group(n, None)).collect();
        // `groups` binds the first triangle window; one more raster group per further window.
        let raster_groups: Vec<(wgpu::BindGroup, usize)> =
            windows[1..].iter().map(|&(base, count, l)| (group(RASTER, Some((base, count))), l)).collect();
        let mut enc =
            d.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("lod::gpu batch") });
        // What the passes accumulate into starts at zero; the other buffers are written before
        // they are read.
        for n in [P_COUNTERS, P_TABLE, P_COLUMNS, P_BITMAP] {
            enc.clear_buffer(&pooled[n], 0, Some(used[n]));
        }
        let mut dispatches = 0u64;
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("bake"),
                timestamp_writes: None,
            });
            let mut run_in =
                |n: usize, group: &wgpu::BindGroup, level: Option<usize>, items: u64, per_group: u64| {
                    if items == 0 {
                        return;
                    }
                    let wgs = items.div_ceil(per_group);
                    let x = wgs.min(u64::from(MAX_GROUPS_X));
                    let y = wgs.div_ceil(x);
                    pass.set_pipeline(&self.pipelines[n]);
                    match level {
                        Some(l) => pass.set_bind_group(0, group, &[(l as u64 * LEVEL_STRIDE) as u32]),
                        None => pass.set_bind_group(0, group, &[]),
                    }
                    pass.dispatch_workgroups(x as u32, y as u32, 1);
                    dispatches += 1;
                };
            let wg = u64::from(WORKGROUP);
            run_in(RASTER, &groups[RASTER], Some(windows[0].2), raster, wg);
            for (g, l) in &raster_groups {
                run_in(RASTER, g, Some(*l), raster, wg);
            }
            let mut run = |n: usize, level: Option<usize>, items: u64, per_group: u64| {
                run_in(n, &groups[n], level, items, per_group);
            };
            // The passes after `raster` run over the cell lists (room `out` in all), not the
            // tables, or over the rows.
            if fill {
                run(COLUMNS, None, out, wg);
                run(FILL, None, cols, wg);
            }
            for &(n, l, items) in &scan_runs {
                run(n, Some(l), items, SCAN_BLOCK);
            }
            run(PLACE, None, out, wg);
        }
        enc.copy_buffer_to_buffer(&pooled[P_COUNTERS], 0, &pooled[P_STAGING], 0, counters_bytes);
        let cmd = enc.finish();
        report.upload_s += t.elapsed().as_secs_f64();
        let t = Instant::now();
        self.queue.submit([cmd]);
        report.submissions += 1;
        report.dispatches += dispatches;
        report.bytes_uploaded += uploaded;
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Wgpu {
                during: format!("batch submission on {}", self.adapter),
                message: e.to_string(),
            });
        }
        let (tx, rx) = mpsc::channel();
        pooled[P_STAGING].slice(..counters_bytes).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        report.submit_s += t.elapsed().as_secs_f64();
        Ok(InFlight { jobs: batch, buffers: pooled, reused, counters_bytes, mapped: rx, bytes })
    }

    fn map_err(e: impl std::fmt::Display) -> GpuError {
        GpuError::Wgpu { during: "read-back mapping".into(), message: e.to_string() }
    }

    fn wait(&self, rx: &mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>) -> Result<(), GpuError> {
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Wgpu {
            during: "waiting for the device".into(),
            message: e.to_string(),
        })?;
        rx.recv()
            .map_err(|_| GpuError::Internal("read-back callback dropped"))?
            .map_err(|e| GpuError::Wgpu { during: "read-back".into(), message: e.to_string() })
    }

    /// Waits for a batch's counters, copies exactly its points (already in their final order)
    /// to the read-back buffer, and turns each job's into the reference's cells.
    pub(super) fn finish<O: JobOutput>(
        &self,
        f: InFlight,
        jobs: &[LevelJob<'_>],
        report: &mut BatchReport,
    ) -> Result<Vec<(Prepared, Decoded<O>)>, GpuError> {
        let t = Instant::now();
        self.wait(&f.mapped)?;
        report.wait_s += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let staging = &f.buffers[P_STAGING];
        // Each job's points start after the points of the jobs before it: as many as the bits
        // they set, their list length within their room.
        let mut starts = Vec::with_capacity(f.jobs.len());
        let checked: Vec<Result<_, _>> = {
            let view = staging.slice(..f.counters_bytes).get_mapped_range().map_err(Self::map_err)?;
            let counters: &[u32] = bytemuck::cast_slice(&view);
            let mut total = 0u64;
            f.jobs
                .iter()
                .enumerate()
                .map(|(n, p)| {
                    let c = &counters[n * COUNTER_WORDS..(n + 1) * COUNTER_WORDS];
                    let len = u64::from(c[0]).min(p.out_cap);
                    starts.push((total, len));
                    total += len;
                    check(p, c)
                })
                .collect()
        };
        staging.unmap();
        let total: u64 = starts.last().map_or(0, |&(s, l)| s + l);
        let points_bytes = total * POINT_BYTES;
        report.map_s += t.elapsed().as_secs_f64();
        report.bytes_read_back += f.counters_bytes;
        if points_bytes > 0 {
            let t = Instant::now();
            let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("lod::gpu read-back"),
            });
            enc.copy_buffer_to_buffer(&f.buffers[P_OUT], 0, staging, f.counters_bytes, points_bytes);
            self.queue.submit([enc.finish()]);
            report.submissions += 1;
            let (tx, rx) = mpsc::channel();
            staging.slice(f.counters_bytes..f.counters_bytes + points_bytes).map_async(
                wgpu::MapMode::Read,
                move |r| {
                    let _ = tx.send(r);
                },
            );
            report.submit_s += t.elapsed().as_secs_f64();
            let t = Instant::now();
            self.wait(&rx)?;
            report.wait_s += t.elapsed().as_secs_f64();
            report.bytes_read_back += points_bytes;
            report.points += total;
        }
        let t = Instant::now();
        let out: Vec<(Prepared, Decoded<O>)> = {
            let view = (points_bytes > 0)
                .then(|| staging.slice(f.counters_bytes..f.counters_bytes + points_bytes).get_mapped_range())
                .transpose()
                .map_err(Self::map_err)?;
            let all: &[u32] = view.as_deref().map_or(&[], bytemuck::cast_slice);
            let t_map = t.elapsed().as_secs_f64();
            let busy = AtomicU64::new(0);
            let out = f
                .jobs
                .into_par_iter()
                .zip(checked)
                .zip(starts.par_iter())
                .map(|((p, c), &(start, len))| {
                    let r = c.map(|stats| {
                        let w = (start * 8) as usize..((start + len) * 8) as usize;
                        timed(&busy, || convert(&p, &jobs[p.job], stats, &all[w]))
                    });
                    (p, r)
                })
                .collect();
            report.convert_s += busy_s(&busy);
            report.map_s += t_map;
            out
        };
        let t = Instant::now();
        if points_bytes > 0 {
            staging.unmap();
        }
        report.map_s += t.elapsed().as_secs_f64();
        if let Ok(mut pool) = self.pool.lock()
            && pool.len() < POOL_SETS
        {
            pool.push(f.buffers);
        }
        Ok(out)
    }

    /// The pooled buffers for a batch that uses `used` bytes of each (`POOLED` order) and
    /// `other` bytes elsewhere: a kept buffer is reused when it is large enough, at most twice
    /// the size used (so a small batch does not pin a large one) and the batch's total stays
    /// within the budget (or within what the batch needs, for a single job over it); any other
    /// is allocated at the size used. Returns the buffers and how many were reused.
    pub(super) fn take_buffers(&self, used: [u64; N_POOLED], other: u64) -> ([wgpu::Buffer; N_POOLED], u64) {
        let kept = self.pool.lock().ok().and_then(|mut p| p.pop());
        let mut kept: [Option<wgpu::Buffer>; N_POOLED] = match kept {
            Some(set) => set.map(Some),
            None => Default::default(),
        };
        let needed = other + used.iter().sum::<u64>();
        let limit = self.budget.max(needed);
        let mut total = needed;
        let mut reused = 0;
        let set = std::array::from_fn(|n| {
            if let Some(b) = kept[n].take() {
                let size = b.size();
                if size >= used[n] && size <= 2 * used[n] && total - used[n] + size <= limit {
                    total = total - used[n] + size;
                    reused += 1;
                    return b;
                }
            }
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(POOLED[n].0),
                size: used[n].next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT),
                usage: POOLED[n].1,
                mapped_at_creation: false,
            })
        });
        (set, reused)
    }
}
