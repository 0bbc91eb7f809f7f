//! Batching: concurrent requests for one model gathered into one inference.
//!
//! Each model has a bounded queue and its own worker threads (ONNX Runtime
//! calls block, so they never run on the async runtime). A worker takes the
//! first waiting job, then keeps taking jobs until the batch is full or the
//! first job has waited `max_wait`, runs the model once on all of them and
//! answers each. Jobs whose caller has gone (a cancelled request) are dropped
//! before inference. A full queue is reported at once rather than growing
//! memory.

use std::sync::mpsc::{self, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::oneshot;

use super::runtime::RuntimeError;
use humem_core::observe::SharedObserver;

/// A model that runs on batches.
pub trait BatchModel: Send + 'static {
    /// What one job hands the model (one image, one text line, …).
    type Input: Send + 'static;
    /// What the model gives back for one input.
    type Output: Send + 'static;

    /// Runs one batch; returns one output per input, in order.
    fn run(&mut self, inputs: Vec<Self::Input>) -> Result<Vec<Self::Output>, RuntimeError>;
}

/// How a model's requests are batched.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BatchConfig {
    /// Most inputs per inference.
    pub max_batch: usize,
    /// Longest the first job of a batch waits for company.
    pub max_wait: Duration,
    /// Most jobs waiting.
    pub queue: usize,
}

/// An output with how it was made.
#[derive(Debug)]
pub struct Inferred<O> {
    /// The model's output for this job's input.
    pub output: O,
    /// Inputs in the inference that made it.
    pub batch_size: usize,
    /// Time the inference took (shared by the whole batch).
    pub inference: Duration,
    /// Time the job waited before its inference started.
    pub queued: Duration,
}

/// Why a job got no output.
#[derive(Debug, Clone, thiserror::Error)]
pub enum BatchError {
    /// The model's queue is full; the job was not queued.
    #[error("model {model} is busy ({queue} jobs waiting); retry shortly")]
    Busy {
        /// The batcher's name (the model's role).
        model: &'static str,
        /// The queue's capacity, in jobs.
        queue: usize,
    },
    /// The model's workers have gone, so the job got no answer.
    #[error("model {model} has stopped")]
    Stopped {
        /// The batcher's name (the model's role).
        model: &'static str,
    },
    /// The inference failed.
    #[error(transparent)]
    Runtime(#[from] RuntimeError),
}

type Reply<O> = oneshot::Sender<Result<Inferred<O>, BatchError>>;

struct Job<M: BatchModel> {
    input: M::Input,
    reply: Reply<M::Output>,
    enqueued: Instant,
}

/// The sending side of a model's batcher; cheap to clone.
pub struct Batcher<M: BatchModel> {
    name: &'static str,
    queue: SyncSender<Job<M>>,
    capacity: usize,
    observer: SharedObserver,
}

impl<M: BatchModel> Clone for Batcher<M> {
    fn clone(&self) -> Self {
        Batcher {
            name: self.name,
            queue: self.queue.clone(),
            capacity: self.capacity,
            observer: self.observer.clone(),
        }
    }
}

impl<M: BatchModel> Batcher<M> {
    /// Starts one worker thread per model instance; the queue's depth and
    /// each batch's size are reported to `observer` under `name`.
    pub fn spawn(
        name: &'static str,
        models: Vec<M>,
        config: BatchConfig,
        observer: SharedObserver,
    ) -> Batcher<M> {
        let capacity = config.queue.max(1);
        let (queue, receiver) = mpsc::sync_channel::<Job<M>>(capacity);
        let receiver = Arc::new(Mutex::new(receiver));
        for (i, mut model) in models.into_iter().enumerate() {
            let receiver = receiver.clone();
            let observer = observer.clone();
            std::thread::Builder::new()
                .name(format!("humem-{name}-{i}"))
                .spawn(move || loop {
                    let batch = {
                        let Ok(receiver) = receiver.lock() else {
                            return;
                        };
                        match gather(&receiver, config) {
                            Some(batch) => batch,
                            None => return,
                        }
                    };
                    observer.depth_changed(name, -(batch.len() as i64));
                    observer.batch_ran(name, batch.len());
                    run_batch(&mut model, batch);
                })
                .expect("spawning a model worker thread");
        }
        Batcher {
            name,
            queue,
            capacity,
            observer,
        }
    }

    /// Queues one input and waits for its output.
    pub async fn infer(&self, input: M::Input) -> Result<Inferred<M::Output>, BatchError> {
        let (reply, answer) = oneshot::channel();
        let job = Job {
            input,
            reply,
            enqueued: Instant::now(),
        };
        // Counted before sending, so the worker's decrement never comes first.
        self.observer.depth_changed(self.name, 1);
        self.queue.try_send(job).map_err(|e| {
            self.observer.depth_changed(self.name, -1);
            match e {
                TrySendError::Full(_) => BatchError::Busy {
                    model: self.name,
                    queue: self.capacity,
                },
                TrySendError::Disconnected(_) => BatchError::Stopped { model: self.name },
            }
        })?;
        answer
            .await
            .map_err(|_| BatchError::Stopped { model: self.name })?
    }
}

/// Waits for a first job, then gathers more until the batch is full or the
/// first job has waited long enough. `None` when the queue is closed.
fn gather<M: BatchModel>(
    receiver: &mpsc::Receiver<Job<M>>,
    config: BatchConfig,
) -> Option<Vec<Job<M>>> {
    let first = receiver.recv().ok()?;
    let deadline = first.enqueued + config.max_wait;
    let mut batch = vec![first];
    while batch.len() < config.max_batch.max(1) {
        let wait = deadline.saturating_duration_since(Instant::now());
        let next = if wait.is_zero() {
            receiver.try_recv().map_err(|_| RecvTimeoutError::Timeout)
        } else {
            receiver.recv_timeout(wait)
        };
        match next {
            Ok(job) => batch.push(job),
            Err(_) => break,
        }
    }
    Some(batch)
}

fn run_batch<M: BatchModel>(model: &mut M, batch: Vec<Job<M>>) {
    // Callers that gave up need no inference.
    let batch: Vec<Job<M>> = batch.into_iter().filter(|j| !j.reply.is_closed()).collect();
    if batch.is_empty() {
        return;
    }
    let started = Instant::now();
    let (inputs, waiting): (Vec<_>, Vec<_>) = batch
        .into_iter()
        .map(|j| (j.input, (j.reply, started.duration_since(j.enqueued))))
        .unzip();
    let batch_size = inputs.len();
    let result = model.run(inputs);
    let inference = started.elapsed();
    match result {
        Ok(outputs) if outputs.len() == batch_size => {
            for ((reply, queued), output) in waiting.into_iter().zip(outputs) {
                let _ = reply.send(Ok(Inferred {
                    output,
                    batch_size,
                    inference,
                    queued,
                }));
            }
        }
        Ok(outputs) => {
            let error = RuntimeError::Run {
                model: std::any::type_name::<M>().into(),
                message: format!("{} outputs for {batch_size} inputs", outputs.len()),
            };
            for (reply, _) in waiting {
                let _ = reply.send(Err(error.clone().into()));
            }
        }
        Err(error) => {
            for (reply, _) in waiting {
                let _ = reply.send(Err(error.clone().into()));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// Doubles its inputs and records the batch sizes it saw.
    struct Doubler(Arc<Mutex<Vec<usize>>>);

    impl BatchModel for Doubler {
        type Input = u32;
        type Output = u32;
        fn run(&mut self, inputs: Vec<u32>) -> Result<Vec<u32>, RuntimeError> {
            self.0.lock().unwrap().push(inputs.len());
            std::thread::sleep(Duration::from_millis(5));
            Ok(inputs.into_iter().map(|v| 2 * v).collect())
        }
    }

    fn config(max_batch: usize, wait_ms: u64) -> BatchConfig {
        BatchConfig {
            max_batch,
            max_wait: Duration::from_millis(wait_ms),
            queue: 64,
        }
    }

    #[tokio::test(flavor = "multi_thread")]
    async fn concurrent_jobs_share_inferences_and_keep_their_answers() {
        let sizes = Arc::new(Mutex::new(Vec::new()));
        let batcher = Batcher::spawn(
            "doubler",
            vec![Doubler(sizes.clone())],
            config(8, 50),
            humem_core::observe::unobserved(),
        );
        let tasks: Vec<_> = (0..16u32)
            .map(|i| {
                let b = batcher.clone();
                tokio::spawn(async move { (i, b.infer(i).await.unwrap()) })
            })
            .collect();
        for task in tasks {
            let (i, out) = task.await.unwrap();
            assert_eq!(out.output, 2 * i);
            assert!(out.batch_size >= 1 && out.batch_size <= 8);
        }
        let sizes = sizes.lock().unwrap();
        assert_eq!(sizes.iter().sum::<usize>(), 16);
        assert!(sizes.iter().all(|&s| s <= 8));
        // 16 jobs arriving together need far fewer than 16 inferences.
        assert!(sizes.len() <= 4, "batches: {sizes:?}");
    }

    #[tokio::test]
    async fn a_lone_job_waits_at_most_max_wait() {
        let sizes = Arc::new(Mutex::new(Vec::new()));
        let batcher = Batcher::spawn(
            "doubler",
            vec![Doubler(sizes.clone())],
            config(8, 1),
            humem_core::observe::unobserved(),
        );
        let out = batcher.infer(21).await.unwrap();
        assert_eq!((out.output, out.batch_size), (42, 1));
    }

    struct Failing(Arc<AtomicUsize>);

    impl BatchModel for Failing {
        type Input = ();
        type Output = ();
        fn run(&mut self, _: Vec<()>) -> Result<Vec<()>, RuntimeError> {
            self.0.fetch_add(1, Ordering::SeqCst);
            Err(RuntimeError::Run {
                model: "failing".into(),
                message: "boom".into(),
            })
        }
    }

    #[tokio::test]
    async fn failures_reach_every_caller_and_a_full_queue_says_busy() {
        let runs = Arc::new(AtomicUsize::new(0));
        let batcher = Batcher::spawn(
            "failing",
            vec![Failing(runs.clone())],
            config(4, 1),
            humem_core::observe::unobserved(),
        );
        assert!(matches!(
            batcher.infer(()).await,
            Err(BatchError::Runtime(_))
        ));
    }

    /// Runs only when the test lets it.
    struct Gated(Mutex<mpsc::Receiver<()>>);

    impl BatchModel for Gated {
        type Input = ();
        type Output = ();
        fn run(&mut self, inputs: Vec<()>) -> Result<Vec<()>, RuntimeError> {
            let _ = self.0.lock().unwrap().recv();
            Ok(inputs)
        }
    }

    #[tokio::test(flavor = "multi_thread")]
    async fn a_full_queue_says_busy() {
        let (open, gate) = mpsc::channel();
        let batcher = Batcher::spawn(
            "gated",
            vec![Gated(Mutex::new(gate))],
            BatchConfig {
                queue: 1,
                ..config(1, 0)
            },
            humem_core::observe::unobserved(),
        );
        // The first job is taken by the worker and blocks it; the second
        // fills the queue; the third is refused.
        let first = tokio::spawn({
            let b = batcher.clone();
            async move { b.infer(()).await }
        });
        tokio::time::sleep(Duration::from_millis(50)).await;
        let second = tokio::spawn({
            let b = batcher.clone();
            async move { b.infer(()).await }
        });
        tokio::time::sleep(Duration::from_millis(50)).await;
        assert!(matches!(
            batcher.infer(()).await,
            Err(BatchError::Busy { queue: 1, .. })
        ));
        open.send(()).unwrap();
        open.send(()).unwrap();
        first.await.unwrap().unwrap();
        second.await.unwrap().unwrap();
    }
}
