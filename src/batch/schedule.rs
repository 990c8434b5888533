//! How a batch shares the machine among images: how many are in flight, and how many threads
//! each one's stages and render get.
//!
//! Each image in flight runs on its own thread pool. One pool shared by every image (the way
//! a batch ran before) nests each image's parallel loops inside the others' and leaves the
//! serial parts (decoding, Telea's march, encoding) to wait on the shared queue: on a 16-core
//! machine that batch reached 42% of what 16 single-threaded processes did (issue 43). An
//! image on few threads spends almost nothing on synchronisation, so when there are images
//! enough for every core, one thread each is the most work per second; when there are fewer
//! (a short batch, or a memory budget that holds only a few large photos at once), the cores
//! are split among those that can be in flight.

/// The batch's workers: each takes the next image and renders it on its own thread pool.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Schedule {
    /// Threads of worker i's pool; one worker per image in flight.
    pub threads: Vec<usize>,
}

/// What the schedule is chosen from.
#[derive(Clone, Copy, Debug)]
pub struct Machine {
    /// Threads the whole batch may use (`--threads`, else one per core).
    pub cores: usize,
    /// Images the batch will render.
    pub items: usize,
    /// Estimated peak bytes of a typical image's render.
    pub image_bytes: u64,
    /// `[batch] memory_budget_mb` in bytes: images in flight stay under it together.
    pub budget: u64,
}

/// Estimated memory of the images in flight beyond which `auto` puts fewer images in flight,
/// each on more threads: many large renders in one address space contend for its page faults
/// and allocator. Lent 16-core machine, 32 photos of 12.2 MP (~2.4 GB each by the estimate),
/// one window: 16 images on one thread each made 82% of the throughput of 16 separate
/// single-threaded processes (57.6 s of system time against their 23.5 s), 8 on two threads
/// each 97% (22.8 s); 2.1 MP photos, 16 at a time (6.8 GB), matched the processes.
const SHARED_BYTES_IN_FLIGHT: u64 = 20 << 30;

impl Machine {
    /// Images whose estimates fit the budget together; at least one.
    fn fit(&self) -> usize {
        Self::count(self.budget, self.image_bytes)
    }

    /// Images `auto` puts in flight at most: those that fit the budget, and the shared address
    /// space ([`SHARED_BYTES_IN_FLIGHT`]).
    fn auto_fit(&self) -> usize {
        Self::count(self.budget.min(SHARED_BYTES_IN_FLIGHT), self.image_bytes)
    }

    fn count(bytes: u64, each: u64) -> usize {
        usize::try_from(bytes / each.max(1)).unwrap_or(usize::MAX).max(1)
    }
}

/// The schedule for `jobs` images in flight (`None`: as many as fit the budget and
/// [`SHARED_BYTES_IN_FLIGHT`], up to one per core) and
/// `threads_per_image` threads each (`None`: the cores split evenly among the images that can
/// be in flight at once, at least one each). With both given, both are obeyed, whatever the
/// core count. Never more workers than items.
pub fn schedule(m: Machine, jobs: Option<usize>, threads_per_image: Option<usize>) -> Schedule {
    let cores = m.cores.max(1);
    let items = m.items.max(1);
    let workers = match (jobs, threads_per_image) {
        (Some(j), _) => j,
        // Threads each as asked: as many images as leave no core idle, within the budget.
        (None, Some(t)) => (cores / t.max(1)).clamp(1, m.fit()),
        (None, None) => cores.min(m.auto_fit()),
    }
    .clamp(1, items);
    // Workers beyond what the budget holds wait for memory, not for cores: the cores go to
    // those that can run.
    let running = workers.min(m.fit());
    let threads = (0..workers)
        .map(|i| match threads_per_image {
            Some(t) => t.max(1),
            None => (cores / running + usize::from(i % running < cores % running)).max(1),
        })
        .collect();
    Schedule { threads }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MB: u64 = 1 << 20;

    fn machine(cores: usize, items: usize, image_mb: u64, budget_mb: u64) -> Machine {
        Machine { cores, items, image_bytes: image_mb * MB, budget: budget_mb * MB }
    }

    #[test]
    fn many_small_images_get_one_thread_each_on_every_core() {
        let s = schedule(machine(16, 64, 420, 60_000), None, None);
        assert_eq!(s.threads, vec![1; 16]);
    }

    #[test]
    fn fewer_images_than_cores_split_the_cores() {
        assert_eq!(schedule(machine(16, 4, 420, 60_000), None, None).threads, vec![4; 4]);
        // 16 cores over 3 images: 6, 5, 5 (none idle).
        assert_eq!(schedule(machine(16, 3, 420, 60_000), None, None).threads, vec![6, 5, 5]);
    }

    #[test]
    fn the_budget_bounds_the_images_in_flight_and_they_share_the_cores() {
        // 12 MP photos (~2.4 GB each) under 8 GB: three at once, 16 cores among them.
        assert_eq!(schedule(machine(16, 64, 2400, 8192), None, None).threads, vec![6, 5, 5]);
        // One larger than the budget still runs, on every core.
        assert_eq!(schedule(machine(16, 64, 9000, 8192), None, None).threads, vec![16]);
    }

    #[test]
    fn large_photos_go_fewer_at_a_time_on_more_threads_each() {
        // 12.2 MP (~2.4 GB by the estimate) under a 60 GB budget: 8 in flight (19.2 GB), two
        // threads each; 2.1 MP: 16 in flight (6.7 GB), one each.
        assert_eq!(schedule(machine(16, 64, 2440, 60_000), None, None).threads, vec![2; 8]);
        assert_eq!(schedule(machine(16, 64, 420, 60_000), None, None).threads, vec![1; 16]);
        // An explicit --jobs or --threads-per-image is obeyed (the budget holds them all).
        assert_eq!(schedule(machine(16, 64, 2440, 60_000), Some(16), None).threads, vec![1; 16]);
        assert_eq!(schedule(machine(16, 64, 2440, 60_000), None, Some(1)).threads, vec![1; 16]);
    }

    #[test]
    fn given_counts_are_obeyed() {
        // --jobs 1: the old all-cores-on-one-image batch.
        assert_eq!(schedule(machine(16, 64, 420, 60_000), Some(1), None).threads, vec![16]);
        // --jobs 4: the cores split four ways.
        assert_eq!(schedule(machine(16, 64, 420, 60_000), Some(4), None).threads, vec![4; 4]);
        // --jobs beyond the cores: one thread each (oversubscribed, as asked).
        assert_eq!(schedule(machine(2, 64, 420, 60_000), Some(5), None).threads, vec![1; 5]);
        // --threads-per-image 4 alone: as many images as that leaves cores for.
        assert_eq!(schedule(machine(16, 64, 420, 60_000), None, Some(4)).threads, vec![4; 4]);
        // Both given: both obeyed.
        assert_eq!(schedule(machine(16, 64, 420, 60_000), Some(3), Some(2)).threads, vec![2; 3]);
        // Never more workers than items.
        assert_eq!(schedule(machine(16, 2, 420, 60_000), Some(8), None).threads, vec![8, 8]);
    }

    #[test]
    fn degenerate_machines_still_run_one_image() {
        assert_eq!(schedule(machine(0, 0, 0, 0), None, None).threads, vec![1]);
        assert_eq!(schedule(machine(1, 10, 420, 0), None, None).threads, vec![1]);
        assert_eq!(schedule(machine(4, 10, 0, 60_000), None, Some(0)).threads, vec![1; 4]);
    }
}
