//! Credit-based flow control, without dora: what a producer may send and what a consumer
//! returns.
//!
//! dora's zero-copy path drops a message when the receiver's queue is full, and its lossless
//! `queue_policy: backpressure` copies every message through the daemon. Credits keep the
//! zero-copy path and make it lossless: a consumer grants each input its queue's size, a
//! producer never has more messages in flight to a consumer than it was granted, so no queue
//! overflows. The graph wires it: a consumer declares an output `credits`, and each of its
//! producers reads it as an input (any id; its source's output is `credits`).

use std::collections::BTreeMap;

use neuspike_schemas::Credit;

/// The output a consumer returns its credits on.
pub const CREDITS: &str = "credits";

/// What a producer knows of one consumer.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Consumer {
    /// Its first credits (the list of what it reads) have not come yet.
    Waiting,
    /// For each of the producer's outputs it reads: the credits left and its window.
    Ready(BTreeMap<String, Window>),
    /// It ended (its credit input closed): it no longer holds anything back.
    Gone,
}

/// One consumer's credits for one output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Window {
    left: u64,
    size: u64,
}

/// A producer's side: the credits each consumer granted, per output.
#[derive(Clone, Debug)]
pub struct CreditLedger {
    node: String,
    consumers: BTreeMap<String, Consumer>,
}

impl CreditLedger {
    /// A producer `node` whose consumers return credits on the inputs `credit_inputs`.
    pub fn new<S: AsRef<str>>(node: &str, credit_inputs: impl IntoIterator<Item = S>) -> Self {
        CreditLedger {
            node: node.to_string(),
            consumers: credit_inputs
                .into_iter()
                .map(|i| (i.as_ref().to_string(), Consumer::Waiting))
                .collect(),
        }
    }

    /// Whether `input` carries a consumer's credits.
    pub fn is_credit_input(&self, input: &str) -> bool {
        self.consumers.contains_key(input)
    }

    /// Whether any consumer returns credits.
    pub fn is_empty(&self) -> bool {
        self.consumers.is_empty()
    }

    /// Takes a consumer's credit message. Grants for another producer's outputs are ignored
    /// (a consumer's credits go to all its producers).
    pub fn grant(&mut self, input: &str, credit: &Credit) {
        let Some(consumer) = self.consumers.get_mut(input) else {
            return;
        };
        let prefix = format!("{}/", self.node);
        let mine = credit
            .grants
            .iter()
            .filter_map(|(source, n)| source.strip_prefix(&prefix).map(|o| (o, *n)));
        let mine: Vec<(&str, u64)> = mine.collect();
        match consumer {
            Consumer::Gone => {}
            // A first message, or a restarted consumer's (or one that saw this producer restart):
            // the windows start over.
            Consumer::Waiting | Consumer::Ready(_) if credit.hello => {
                if mine.is_empty() && matches!(consumer, Consumer::Ready(_)) {
                    // A hello for the consumer's other producers.
                    return;
                }
                let mut outputs = BTreeMap::new();
                for &(o, n) in &mine {
                    let w = outputs
                        .entry(o.to_string())
                        .or_insert(Window { left: 0, size: 0 });
                    w.left += n;
                    w.size += n;
                }
                *consumer = Consumer::Ready(outputs);
            }
            Consumer::Waiting => {
                tracing::warn!(
                    input,
                    "credits before the consumer's first message: ignored"
                );
            }
            Consumer::Ready(outputs) => {
                for (o, n) in mine {
                    if let Some(w) = outputs.get_mut(o) {
                        w.left = w.left.saturating_add(n).min(w.size);
                    }
                }
            }
        }
    }

    /// Whether there were consumers and every one has ended: what is sent goes nowhere.
    pub fn all_gone(&self) -> bool {
        !self.consumers.is_empty() && self.consumers.values().all(|c| *c == Consumer::Gone)
    }

    /// The consumer on `input` ended: it holds nothing back any more.
    pub fn closed(&mut self, input: &str) {
        if let Some(c) = self.consumers.get_mut(input) {
            *c = Consumer::Gone;
        }
    }

    /// The consumer that holds `output` back, if any: one that has not said what it reads yet,
    /// or one that reads `output` and has no credit left for it.
    pub fn blocked_on(&self, output: &str) -> Option<&str> {
        self.consumers.iter().find_map(|(input, c)| match c {
            Consumer::Waiting => Some(input.as_str()),
            Consumer::Ready(outputs) if outputs.get(output).is_some_and(|w| w.left == 0) => {
                Some(input.as_str())
            }
            _ => None,
        })
    }

    /// The consumer that has not yet taken everything sent on `output`, if any (one that has
    /// not said what it reads counts too): a producer waits for none before it exits, since
    /// messages still in flight when its process ends may be lost.
    pub fn undrained(&self, output: &str) -> Option<&str> {
        self.consumers.iter().find_map(|(input, c)| match c {
            Consumer::Waiting => Some(input.as_str()),
            Consumer::Ready(outputs) if outputs.get(output).is_some_and(|w| w.left < w.size) => {
                Some(input.as_str())
            }
            _ => None,
        })
    }

    /// A message left on `output`: one credit less from every consumer that reads it. Call only
    /// when [`CreditLedger::blocked_on`] is `None`.
    pub fn spend(&mut self, output: &str) {
        for c in self.consumers.values_mut() {
            if let Consumer::Ready(outputs) = c
                && let Some(w) = outputs.get_mut(output)
            {
                w.left = w.left.saturating_sub(1);
            }
        }
    }

    /// Credits left on `output` from the consumer on `input` (`None`: it does not read it, has
    /// not said yet, or ended).
    pub fn left(&self, input: &str, output: &str) -> Option<u64> {
        match self.consumers.get(input) {
            Some(Consumer::Ready(outputs)) => outputs.get(output).map(|w| w.left),
            _ => None,
        }
    }
}

/// One flow-controlled input of a consumer.
#[derive(Clone, Debug)]
struct Return {
    source: String,
    window: u64,
    pending: u64,
}

/// A consumer's side: the credits it owes each input's producer.
#[derive(Clone, Debug, Default)]
pub struct CreditReturns {
    inputs: BTreeMap<String, Return>,
}

impl CreditReturns {
    /// Flow-controlled inputs as `(input id, source "node/output", window)`; a window of 0
    /// counts as 1.
    pub fn new<S: Into<String>>(inputs: impl IntoIterator<Item = (S, S, u64)>) -> Self {
        CreditReturns {
            inputs: inputs
                .into_iter()
                .map(|(id, source, window)| {
                    (
                        id.into(),
                        Return {
                            source: source.into(),
                            window: window.max(1),
                            pending: 0,
                        },
                    )
                })
                .collect(),
        }
    }

    /// The first message: every input with its whole window (`None` without inputs).
    pub fn hello(&self) -> Option<Credit> {
        (!self.inputs.is_empty()).then(|| Credit {
            hello: true,
            grants: self
                .inputs
                .values()
                .map(|r| (r.source.clone(), r.window))
                .collect(),
        })
    }

    /// The producer `node` was restarted: its new process waits for a first message, this one,
    /// which grants every input it feeds its whole window again (`None` when it feeds none).
    pub fn hello_for(&mut self, node: &str) -> Option<Credit> {
        let prefix = format!("{node}/");
        let grants: Vec<(String, u64)> = self
            .inputs
            .values_mut()
            .filter(|r| r.source.starts_with(&prefix))
            .map(|r| {
                r.pending = 0;
                (r.source.clone(), r.window)
            })
            .collect();
        (!grants.is_empty()).then_some(Credit {
            hello: true,
            grants,
        })
    }

    /// One message of `input` was taken off its queue. Credits go back in batches of half the
    /// window (rounded up), so a window of `w` costs `2` credit messages per `w` messages and
    /// the producer never waits while half the window is still free.
    pub fn taken(&mut self, input: &str) -> Option<Credit> {
        let r = self.inputs.get_mut(input)?;
        r.pending += 1;
        if r.pending < r.window.div_ceil(2) {
            return None;
        }
        Self::flush(r)
    }

    /// `n` messages of `input` were lost on the way (a gap in its sequence numbers): their
    /// credits come back with the next batch, or the window would shrink for good.
    pub fn lost(&mut self, input: &str, n: u64) {
        if let Some(r) = self.inputs.get_mut(input) {
            r.pending = r.pending.saturating_add(n);
        }
    }

    /// `input` ended (its end-of-stream marker was taken): everything still owed goes back now,
    /// so that its producer knows every message was taken and may exit.
    pub fn ended(&mut self, input: &str) -> Option<Credit> {
        self.inputs.get_mut(input).and_then(Self::flush)
    }

    fn flush(r: &mut Return) -> Option<Credit> {
        let n = std::mem::take(&mut r.pending);
        (n > 0).then(|| Credit {
            hello: false,
            grants: vec![(r.source.clone(), n)],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn credit(hello: bool, grants: &[(&str, u64)]) -> Credit {
        Credit {
            hello,
            grants: grants.iter().map(|&(s, n)| (s.to_string(), n)).collect(),
        }
    }

    #[test]
    fn a_producer_waits_for_every_consumer_then_spends_what_each_granted() {
        let mut l = CreditLedger::new("align", ["from-represent", "from-cf"]);
        assert!(l.is_credit_input("from-cf") && !l.is_credit_input("spikes"));
        // Nothing leaves before every consumer has said what it reads.
        assert_eq!(l.blocked_on("windows"), Some("from-cf"));
        l.grant("from-represent", &credit(true, &[("align/windows", 2)]));
        assert_eq!(l.blocked_on("windows"), Some("from-cf"));
        // Another producer's grants are not ours.
        l.grant(
            "from-cf",
            &credit(true, &[("align/events", 1), ("represent/isi", 9)]),
        );
        assert_eq!(l.blocked_on("windows"), None);
        assert_eq!(l.left("from-cf", "isi"), None);
        l.spend("windows");
        l.spend("windows");
        assert_eq!(l.blocked_on("windows"), Some("from-represent"));
        // `events` is read by from-cf only.
        assert_eq!(l.blocked_on("events"), None);
        l.spend("events");
        assert_eq!(l.blocked_on("events"), Some("from-cf"));
        // An output nobody reads is never held.
        assert_eq!(l.blocked_on("debug"), None);
        assert_eq!(l.undrained("windows"), Some("from-represent"));
        l.grant("from-represent", &credit(false, &[("align/windows", 1)]));
        assert_eq!(l.blocked_on("windows"), None);
        assert_eq!(l.left("from-represent", "windows"), Some(1));
        // More than the window is never granted.
        l.grant("from-represent", &credit(false, &[("align/windows", 5)]));
        assert_eq!(l.left("from-represent", "windows"), Some(2));
        assert_eq!(l.undrained("windows"), None);
        // A consumer that ended holds nothing back.
        l.closed("from-cf");
        assert_eq!(l.blocked_on("events"), None);
        assert!(!l.all_gone());
        l.closed("from-represent");
        assert!(l.all_gone());
        assert!(!CreditLedger::new("p", Vec::<String>::new()).all_gone());
        l.grant("from-cf", &credit(true, &[("align/events", 5)]));
        assert_eq!(l.left("from-cf", "events"), None);
    }

    #[test]
    fn credits_before_the_first_message_are_ignored() {
        let mut l = CreditLedger::new("p", ["c"]);
        l.grant("c", &credit(false, &[("p/out", 3)]));
        assert_eq!(l.blocked_on("out"), Some("c"));
        l.grant("c", &credit(true, &[("p/out", 1)]));
        assert_eq!(l.left("c", "out"), Some(1));
    }

    #[test]
    fn a_consumer_returns_half_windows_and_the_producer_never_overfills_its_queue() {
        let mut r = CreditReturns::new([("windows", "align/windows", 5), ("truth", "src/gt", 0)]);
        let hello = r.hello().expect("inputs");
        assert!(hello.hello);
        assert_eq!(
            hello.grants,
            [("src/gt".to_string(), 1), ("align/windows".to_string(), 5)]
        );
        assert_eq!(r.taken("windows"), None);
        assert_eq!(r.taken("windows"), None);
        assert_eq!(
            r.taken("windows").map(|c| c.grants),
            Some(vec![("align/windows".to_string(), 3)])
        );
        assert_eq!(r.taken("truth").map(|c| c.grants[0].1), Some(1));
        assert_eq!(r.taken("unknown"), None);
        // Lost messages' credits come back with the next batch; an end returns all that is owed.
        r.lost("windows", 2);
        assert_eq!(
            r.taken("windows").map(|c| c.grants[0].1),
            Some(3),
            "2 lost + 1 taken"
        );
        assert_eq!(r.taken("windows"), None);
        assert_eq!(r.ended("windows").map(|c| c.grants[0].1), Some(1));
        assert_eq!(r.ended("windows"), None, "nothing owed");
        assert!(CreditReturns::default().hello().is_none());

        // A simulated link: a producer sends whenever it may, a consumer with a queue of
        // `window` takes one message every third step; the queue never holds more than the
        // window and every message arrives.
        for window in [1u64, 2, 3, 8] {
            let mut ledger = CreditLedger::new("p", ["c"]);
            let mut returns = CreditReturns::new([("in", "p/out", window)]);
            ledger.grant("c", &returns.hello().expect("hello"));
            let (mut queue, mut sent, mut taken, mut peak) = (0u64, 0u64, 0u64, 0u64);
            for step in 0..300 {
                if sent < 50 && ledger.blocked_on("out").is_none() {
                    ledger.spend("out");
                    sent += 1;
                    queue += 1;
                }
                peak = peak.max(queue);
                if step % 3 == 0 && queue > 0 {
                    queue -= 1;
                    taken += 1;
                    if let Some(c) = returns.taken("in") {
                        ledger.grant("c", &c);
                    }
                }
            }
            assert!(peak <= window, "window {window}: queue reached {peak}");
            assert_eq!((sent, taken), (50, 50), "window {window}");
        }
    }
}
