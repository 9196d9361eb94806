//! A stage without outputs (a sink) on a thread of its own: the chain hands it each call over a
//! bounded channel and goes on; it learns what the calls returned as they come back.

use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, channel, sync_channel};
use std::time::{Duration, Instant};

use eyre::eyre;

use crate::{Flow, Msg, Outbox, Stage, Tallies};

/// Calls a worker may hold before the chain waits for it.
const QUEUED: usize = 32;

/// A call of the stage. It travels by value (a box per message would cost an allocation on the
/// hot path); the channel holds a few dozen.
#[allow(clippy::large_enum_variant)]
enum Call {
    Message {
        input: String,
        msg: Msg,
        origin: i64,
    },
    End {
        input: String,
        count: u64,
    },
    Finish(Tallies),
}

/// What a call returned, and how long it took.
struct Reply {
    flow: eyre::Result<Flow>,
    busy: Duration,
    last: bool,
}

/// The chain's side of a stage on its own thread.
pub(super) struct Worker {
    calls: Option<SyncSender<Call>>,
    replies: Receiver<Reply>,
    busy: Duration,
    /// A flow the stage returned that the chain has not acted on: the first error, or a stop.
    pending: Option<eyre::Result<Flow>>,
}

impl Worker {
    /// Starts `stage` on a thread named for `id`.
    ///
    /// # Errors
    /// No thread could start (the stage is dropped).
    pub(super) fn spawn(id: &str, mut stage: Box<dyn Stage>) -> std::io::Result<Worker> {
        let (calls, rx) = sync_channel::<Call>(QUEUED);
        let (tx, replies) = channel::<Reply>();
        std::thread::Builder::new()
            .name(format!("stage-{id}"))
            .spawn(move || {
                // After the stage stopped, its messages are no longer handed to it.
                let mut stopped = false;
                for call in rx {
                    let mut out = Outbox::new();
                    let start = Instant::now();
                    let (flow, last) = match call {
                        Call::Message { .. } | Call::End { .. } if stopped => continue,
                        Call::Message { input, msg, origin } => {
                            out.set_incoming_origin(Some(origin));
                            (stage.on_message(&input, msg, &mut out), false)
                        }
                        Call::End { input, count } => {
                            (stage.on_end(&input, count, &mut out), false)
                        }
                        Call::Finish(t) => (stage.finish(&t, &mut out).map(|()| Flow::Stop), true),
                    };
                    stopped |= !matches!(flow, Ok(Flow::Continue));
                    let reply = Reply {
                        flow,
                        busy: start.elapsed(),
                        last,
                    };
                    if tx.send(reply).is_err() || last {
                        return;
                    }
                }
            })?;
        Ok(Worker {
            calls: Some(calls),
            replies,
            busy: Duration::ZERO,
            pending: None,
        })
    }

    /// Hands the stage `msg` of `input`; returns what earlier calls returned since (a stop or
    /// an error), else that it goes on.
    pub(super) fn message(&mut self, input: &str, msg: Msg, origin: i64) -> eyre::Result<Flow> {
        self.call(Call::Message {
            input: input.to_string(),
            msg,
            origin,
        })
    }

    /// Hands the stage the end of `input`; as [`Worker::message`].
    pub(super) fn end(&mut self, input: &str, count: u64) -> eyre::Result<Flow> {
        self.call(Call::End {
            input: input.to_string(),
            count,
        })
    }

    fn call(&mut self, call: Call) -> eyre::Result<Flow> {
        let sent = match &self.calls {
            Some(c) => c.send(call).is_ok(),
            None => false,
        };
        if !sent {
            return Err(eyre!("its thread ended"));
        }
        self.poll();
        match self.pending.take() {
            Some(flow) => flow,
            None => Ok(Flow::Continue),
        }
    }

    /// Takes the replies that came, keeping the first error or stop.
    fn poll(&mut self) {
        loop {
            match self.replies.try_recv() {
                Ok(r) => self.take(r),
                Err(TryRecvError::Empty | TryRecvError::Disconnected) => return,
            }
        }
    }

    fn take(&mut self, r: Reply) {
        self.busy += r.busy;
        let keep = matches!(
            (&self.pending, &r.flow),
            (None, Ok(Flow::Stop) | Err(_)) | (Some(Ok(_)), Err(_))
        );
        if keep {
            self.pending = Some(r.flow);
        }
    }

    /// Finishes the stage with `tallies` and waits until it has: its result, or the first error
    /// of a call not yet reported.
    pub(super) fn finish(&mut self, tallies: Tallies) -> eyre::Result<()> {
        let sent = match self.calls.take() {
            Some(c) => c.send(Call::Finish(tallies)).is_ok(),
            None => false,
        };
        if !sent {
            return Err(eyre!("its thread ended before its finish"));
        }
        loop {
            match self.replies.recv() {
                Ok(r) => {
                    let last = r.last;
                    let flow = r.flow.map(|_| ());
                    self.busy += r.busy;
                    if last {
                        return match self.pending.take() {
                            Some(Err(e)) => Err(e),
                            _ => flow,
                        };
                    }
                    if let Err(e) = flow
                        && !matches!(self.pending, Some(Err(_)))
                    {
                        self.pending = Some(Err(e));
                    }
                }
                Err(_) => return Err(eyre!("its thread ended before its finish")),
            }
        }
    }

    /// The stage's time in its calls since the last call of this.
    pub(super) fn take_busy(&mut self) -> Duration {
        std::mem::take(&mut self.busy)
    }
}
