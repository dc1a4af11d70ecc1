//! Batches (the module doc's *Batching and memory*): packing prepared jobs into batches within
//! the budget and the binding limits, recording and submitting a batch's passes, reading it back,
//! and the pooled buffers kept from batch to batch.

use std::sync::mpsc;

use rayon::prelude::*;
use wgpu::util::DeviceExt;

use super::{
    BINDINGS, COLUMN_BYTES, COUNTER_WORDS, Decoded, GpuBaker, GpuError, GpuJob, GpuParams, InFlight,
    LevelJob, MAX_GROUPS_X, P_COLUMNS, P_COUNTERS, P_POINTS, P_STAGING, P_TABLE, P_TRIS, P_VERTS,
    POINT_BYTES, POOL_SETS, POOLED, Prepared, SLOT_BYTES, WORKGROUP, decode,
};

impl GpuBaker {
    pub(super) fn fits_bindings(&self, p: &Prepared, fill: bool) -> bool {
        let m = self.max_binding;
        p.table_slots * SLOT_BYTES <= m
            && p.out_cap * POINT_BYTES <= m
            && p.columns(fill) * COLUMN_BYTES <= m
            && p.verts.len() as u64 * 4 <= m
            && p.tris.len() as u64 * 4 <= m
    }

    /// Takes jobs from the front of `queue` while the batch stays within the budget, the
    /// binding limits and 32-bit item counts.
    pub(super) fn take_batch(
        &self,
        queue: &mut std::collections::VecDeque<Prepared>,
        fill: bool,
    ) -> Vec<Prepared> {
        let mut batch = Vec::new();
        let (mut bytes, mut slots, mut out, mut cols, mut verts, mut tris) =
            (0u64, 0u64, 0u64, 0u64, 0u64, 0u64);
        let limit_items = u64::from(u32::MAX / 2);
        while let Some(p) = queue.front() {
            let nb = bytes + p.bytes(fill);
            let ns = slots + p.table_slots;
            let no = out + p.out_cap;
            let nc = cols + p.columns(fill);
            let nv = verts + p.verts.len() as u64;
            let nt = tris + p.tris.len() as u64;
            let fits = nb <= self.budget
                && ns * SLOT_BYTES <= self.max_binding
                && no * POINT_BYTES <= self.max_binding
                && nc * COLUMN_BYTES <= self.max_binding
                && nv * 4 <= self.max_binding
                && nt * 4 <= self.max_binding
                && ns.max(nc).max(nt / 2) <= limit_items;
            if !fits && !batch.is_empty() {
                break;
            }
            (bytes, slots, out, cols, verts, tris) = (nb, ns, no, nc, nv, nt);
            if let Some(p) = queue.pop_front() {
                batch.push(p);
            }
        }
        batch
    }

    /// Uploads a batch, records the passes and the read-back copy, and submits.
    pub(super) fn submit(
        &self,
        batch: Vec<Prepared>,
        jobs: &[LevelJob<'_>],
        fill: bool,
    ) -> Result<InFlight, GpuError> {
        let _ = jobs;
        let mut gjobs = Vec::with_capacity(batch.len());
        let mut verts: Vec<f32> = Vec::new();
        let mut tris: Vec<u32> = Vec::new();
        let (mut raster, mut slots, mut out, mut cols) = (0u64, 0u64, 0u64, 0u64);
        let mut out_offsets = Vec::with_capacity(batch.len());
        for p in &batch {
            let tri_count = (p.tris.len() / 6) as u64;
            gjobs.push(GpuJob {
                tri_start: (tris.len() / 6) as u32,
                tri_count: tri_count as u32,
                vert_start: (verts.len() / 3) as u32,
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
                pad: [0; 3],
            });
            out_offsets.push(out);
            verts.extend_from_slice(&p.verts);
            tris.extend_from_slice(&p.tris);
            raster += tri_count * 3;
            slots += p.table_slots;
            out += p.out_cap;
            cols += p.columns(fill);
        }
        let params = GpuParams {
            n_jobs: gjobs.len() as u32,
            raster_items: raster as u32,
            slots: slots as u32,
            col_items: cols as u32,
            out_items: out as u32,
            pad: [0; 3],
        };
        let d = &self.device;
        let scope = d.push_error_scope(wgpu::ErrorFilter::Validation);
        let init = |label: &str, bytes: &[u8], usage: wgpu::BufferUsages| {
            // Bindings may not be empty.
            let padded;
            let contents = if bytes.is_empty() {
                padded = [0u8; 16];
                &padded[..]
            } else {
                bytes
            };
            d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
        };
        let storage = wgpu::BufferUsages::STORAGE;
        let counters_bytes = (gjobs.len() * COUNTER_WORDS * 4) as u64;
        let out_bytes = out * POINT_BYTES;
        let b_params = init("params", bytemuck::bytes_of(&params), wgpu::BufferUsages::UNIFORM);
        let b_jobs = init("jobs", bytemuck::cast_slice(&gjobs), storage);
        // Sizes the batch uses in each pooled buffer (bindings may not be empty).
        let used = [
            verts.len() as u64 * 4,
            tris.len() as u64 * 4,
            counters_bytes,
            slots * SLOT_BYTES,
            cols * COLUMN_BYTES,
            out_bytes,
            counters_bytes + out_bytes,
        ]
        .map(|b| b.max(16));
        let (pooled, reused) = self.take_buffers(used, b_params.size() + b_jobs.size());
        if !verts.is_empty() {
            self.queue.write_buffer(&pooled[P_VERTS], 0, bytemuck::cast_slice(&verts));
        }
        if !tris.is_empty() {
            self.queue.write_buffer(&pooled[P_TRIS], 0, bytemuck::cast_slice(&tris));
        }
        let bytes = b_params.size() + b_jobs.size() + pooled.iter().map(wgpu::Buffer::size).sum::<u64>();
        let part = |n: usize| {
            wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &pooled[n],
                offset: 0,
                size: std::num::NonZeroU64::new(used[n]),
            })
        };
        // Binding order (`common.wgsl`): params, jobs, counters, table, columns, verts, tris,
        // points.
        let resources = [
            b_params.as_entire_binding(),
            b_jobs.as_entire_binding(),
            part(P_COUNTERS),
            part(P_TABLE),
            part(P_COLUMNS),
            part(P_VERTS),
            part(P_TRIS),
            part(P_POINTS),
        ];
        let groups: Vec<wgpu::BindGroup> = BINDINGS
            .iter()
            .zip(&self.layouts)
            .map(|(bindings, layout)| {
                let entries: Vec<wgpu::BindGroupEntry<'_>> = bindings
                    .iter()
                    .map(|&(binding, _)| wgpu::BindGroupEntry {
                        binding,
                        resource: resources[binding as usize].clone(),
                    })
                    .collect();
                d.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("lod::gpu batch"),
                    layout,
                    entries: &entries,
                })
            })
            .collect();
        let mut enc =
            d.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("lod::gpu batch") });
        // What the passes accumulate into starts at zero; the inputs are overwritten above and
        // the points are written before they are read (`compact` fills every listed record).
        for n in [P_COUNTERS, P_TABLE, P_COLUMNS] {
            enc.clear_buffer(&pooled[n], 0, Some(used[n]));
        }
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("bake"),
                timestamp_writes: None,
            });
            let mut run = |n: usize, items: u64| {
                if items == 0 {
                    return;
                }
                let wgs = items.div_ceil(u64::from(WORKGROUP));
                let x = wgs.min(u64::from(MAX_GROUPS_X));
                let y = wgs.div_ceil(x);
                pass.set_pipeline(&self.pipelines[n]);
                pass.set_bind_group(0, &groups[n], &[]);
                pass.dispatch_workgroups(x as u32, y as u32, 1);
            };
            // Pipelines in `SHADERS` order: raster, columns, fill, compact. The passes after
            // `raster` run over the cell lists (room `out` in all), not the tables.
            run(0, raster);
            if fill {
                run(1, out);
                run(2, cols);
            }
            run(3, out);
        }
        let staging = &pooled[P_STAGING];
        enc.copy_buffer_to_buffer(&pooled[P_COUNTERS], 0, staging, 0, counters_bytes);
        if out_bytes > 0 {
            enc.copy_buffer_to_buffer(&pooled[P_POINTS], 0, staging, counters_bytes, out_bytes);
        }
        self.queue.submit([enc.finish()]);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Wgpu {
                during: format!("batch submission on {}", self.adapter),
                message: e.to_string(),
            });
        }
        let (tx, rx) = mpsc::channel();
        let staging_bytes = counters_bytes + out_bytes;
        staging.slice(..staging_bytes).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        Ok(InFlight {
            jobs: batch,
            buffers: pooled,
            staging_bytes,
            reused,
            counters_bytes,
            out_offsets,
            mapped: rx,
            bytes,
        })
    }

    /// Waits for a batch's read-back and decodes each job.
    pub(super) fn finish(
        &self,
        f: InFlight,
        jobs: &[LevelJob<'_>],
    ) -> Result<Vec<(Prepared, Decoded)>, GpuError> {
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Wgpu {
            during: "waiting for the device".into(),
            message: e.to_string(),
        })?;
        f.mapped
            .recv()
            .map_err(|_| GpuError::Internal("read-back callback dropped"))?
            .map_err(|e| GpuError::Wgpu { during: "read-back".into(), message: e.to_string() })?;
        let out = {
            let view = f.buffers[P_STAGING]
                .slice(..f.staging_bytes)
                .get_mapped_range()
                .map_err(|e| GpuError::Wgpu { during: "read-back mapping".into(), message: e.to_string() })?;
            let words: &[u32] = bytemuck::cast_slice(&view);
            let counters = &words[..f.counters_bytes as usize / 4];
            let points = &words[f.counters_bytes as usize / 4..];
            f.jobs
                .into_par_iter()
                .zip(f.out_offsets.par_iter())
                .enumerate()
                .map(|(n, (p, &off))| {
                    let c = &counters[n * COUNTER_WORDS..(n + 1) * COUNTER_WORDS];
                    let r = decode(&p, &jobs[p.job], c, &points[off as usize * 8..]);
                    (p, r)
                })
                .collect()
        };
        f.buffers[P_STAGING].unmap();
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
    pub(super) fn take_buffers(&self, used: [u64; 7], other: u64) -> ([wgpu::Buffer; 7], u64) {
        let kept = self.pool.lock().ok().and_then(|mut p| p.pop());
        let mut kept: [Option<wgpu::Buffer>; 7] = match kept {
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
