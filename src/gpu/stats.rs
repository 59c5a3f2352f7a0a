//! Pipeline-statistics queries around each dispatch: the compute-shader invocations it
//! really ran (an indirect dispatch's too), summed into every scope around it.
//!
//! Vulkan lets one pipeline-statistics query be active at a time in a command buffer, so
//! scopes, which nest, cannot each hold one; a query around every dispatch (dispatches never
//! nest) counts the same, attributed to the scopes open when the dispatch was recorded.

use ash::vk;

use super::error::{vk_err, Result};
use super::profiler::PassTime;

/// Dispatch counters one pool holds (vkrt's own recorders add pools as they fill).
pub(crate) const COUNTS_PER_POOL: u32 = 16_384;

/// The counting side of a recording: pools, and which scope each counted dispatch was in.
pub(crate) struct DispatchCounts {
    pub(crate) pools: Vec<vk::QueryPool>,
    capacity: u32,
    /// Whether the recorder may add pools while recording.
    grow: bool,
    /// The innermost open scope of each counted dispatch, by query.
    owners: Vec<Option<usize>>,
    /// Dispatches left uncounted because the queries ran out.
    uncounted: usize,
}

impl DispatchCounts {
    pub(crate) fn new(pool: vk::QueryPool, capacity: u32, grow: bool) -> Self {
        Self {
            pools: vec![pool],
            capacity,
            grow,
            owners: Vec::new(),
            uncounted: 0,
        }
    }

    /// Whether the next dispatch needs a pool the recorder should add first.
    pub(crate) fn wants_pool(&self) -> bool {
        self.grow && self.owners.len() as u64 >= u64::from(self.capacity) * self.pools.len() as u64
    }

    /// A further pool; `None` stops growing (the rest is counted as uncounted).
    pub(crate) fn add_pool(&mut self, pool: Option<vk::QueryPool>) {
        match pool {
            Some(p) => self.pools.push(p),
            None => self.grow = false,
        }
    }

    /// The query counting the next dispatch (inside scope `owner`), if one is left.
    pub(crate) fn take(&mut self, owner: Option<usize>) -> Option<(vk::QueryPool, u32)> {
        let q = self.owners.len() as u64;
        let pool = self.pools.get((q / u64::from(self.capacity)) as usize);
        match pool {
            Some(&pool) => {
                self.owners.push(owner);
                Some((pool, (q % u64::from(self.capacity)) as u32))
            }
            None => {
                self.uncounted += 1;
                None
            }
        }
    }

    /// Reads the counts (the work has completed) and adds each to its scope and every
    /// scope around it; every scope gets a count, zero without a dispatch inside.
    pub(crate) fn attribute(&self, device: &ash::Device, passes: &mut [PassTime]) -> Result<()> {
        let mut counts = vec![0u64; self.owners.len()];
        for (i, chunk) in counts.chunks_mut(self.capacity as usize).enumerate() {
            // SAFETY: the work writing these queries (the first `chunk.len()` of this pool)
            // has completed; each query has one statistic, one u64.
            unsafe {
                device.get_query_pool_results(
                    self.pools[i],
                    0,
                    chunk,
                    vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                )
            }
            .map_err(vk_err("vkGetQueryPoolResults"))?;
        }
        for p in passes.iter_mut() {
            p.invocations = Some(0);
        }
        for (&owner, &n) in self.owners.iter().zip(&counts) {
            let mut up = owner;
            while let Some(i) = up {
                *passes[i].invocations.get_or_insert(0) += n;
                up = passes[i].parent;
            }
        }
        if self.uncounted > 0 {
            log::warn!(
                "{} of {} dispatches uncounted: the recorder's {} pipeline-statistics queries \
                 ran out (Recorder::from_raw's query capacity sizes them)",
                self.uncounted,
                self.uncounted + self.owners.len(),
                self.owners.len()
            );
        }
        Ok(())
    }
}

/// A pool of `capacity` pipeline-statistics queries counting compute-shader invocations.
pub(crate) fn create_counts_pool(device: &ash::Device, capacity: u32) -> Result<vk::QueryPool> {
    let info = vk::QueryPoolCreateInfo::default()
        .query_type(vk::QueryType::PIPELINE_STATISTICS)
        .pipeline_statistics(vk::QueryPipelineStatisticFlags::COMPUTE_SHADER_INVOCATIONS)
        .query_count(capacity);
    // SAFETY: valid device with `pipelineStatisticsQuery` enabled (the caller checks).
    unsafe { device.create_query_pool(&info, None) }.map_err(vk_err("vkCreateQueryPool"))
}
