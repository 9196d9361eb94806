//! What every event reader shares: options, counters, the [`EventReader`] trait and the checks
//! each decoded event goes through (sensor bounds, time order) before it reaches the caller.

use std::fmt;
use std::path::{Path, PathBuf};

use neuspike_schemas::{Event, EventBatch};

use crate::error::{FormatError, Location, Result};

/// A sensor size in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Resolution {
    /// Columns.
    pub width: u16,
    /// Rows.
    pub height: u16,
}

impl Resolution {
    /// `width x height`.
    pub const fn new(width: u16, height: u16) -> Self {
        Resolution { width, height }
    }
}

impl fmt::Display for Resolution {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}x{}", self.width, self.height)
    }
}

/// What a reader does with an event earlier than the one before it.
///
/// Equal timestamps are always legal (events are in non-decreasing time order, as [`EventBatch`]
/// requires); only a step backwards is disorder.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Disorder {
    /// Stop with [`FormatError::Unsorted`] naming the place and both timestamps (default).
    #[default]
    Error,
    /// Keep the event, stamped with the previous event's time, and count it in
    /// [`ReadStats::clamped_timestamps`].
    Clamp,
}

/// What a binary reader does with a word whose type its format does not define.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum UnknownWords {
    /// Stop with [`FormatError::UnknownWord`] naming the offset and the word (default).
    #[default]
    Error,
    /// Skip the word and count it in [`ReadStats::unknown_words`].
    Skip,
}

/// An AEDAT 4 packet's limit (also `aedat4::MAX_PACKET_BYTES`).
///
/// The most bytes one packet may take, stored or decompressed, unless
/// [`ReadOptions::max_packet_bytes`] (or `Aedat4Frames::with_max_packet_bytes`) says otherwise:
/// 64 MiB. A DV event packet holds thousands of 16-byte events (a million, 16 MB, at 100 million
/// events a second in 10 ms packets) and a frame packet one APS frame (a DAVIS346 frame is
/// 180 KB, a 4K BGRA frame 33 MB). A packet that claims more, or whose LZ4 or Zstd payload
/// expands to more, is an error that names this limit: one bad packet header or one compressed
/// bomb must not take a node's memory.
pub const MAX_PACKET_BYTES: usize = 64 << 20;

/// A text recording's line limit (also `text::MAX_LINE_BYTES`).
///
/// The most bytes one line may hold before its line feed, unless
/// [`ReadOptions::max_line_bytes`] says otherwise: 4 KiB. An event line is under 100 bytes
/// (`1234567.123456789 65535 65535 1`); the limit keeps a file without a line feed (a binary
/// file, a damaged one) from being read whole into one line.
pub const MAX_LINE_BYTES: usize = 4 * 1024;

/// The most events one packet of a word stream may hold unless
/// [`ReadOptions::max_events_per_packet`] says otherwise: 2^22 (4,194,304; 54 MB of events). A
/// camera's driver sends a packet every millisecond or so, a few thousand to a few hundred thousand
/// events; EVT 3.0 vector words can make 6 events of each byte, so without it one 64 MiB message
/// would make 400 million.
pub const MAX_EVENTS_PER_PACKET: usize = 1 << 22;

/// How to read an event file.
#[derive(Clone, Debug)]
pub struct ReadOptions {
    /// The sensor size, for files that do not state it (the Event Camera Dataset text without its
    /// `W H` line, RAW files without a `geometry`/`format` line, DAT files without `Width` and
    /// `Height`). When the file states a size too, both must agree.
    pub resolution: Option<Resolution>,
    /// Events earlier than their predecessor.
    pub disorder: Disorder,
    /// Undefined word types in binary formats.
    pub unknown_words: UnknownWords,
    /// Read a file that states no sensor size, with no `resolution` given, without checking
    /// events against a sensor (what [`crate::info()`] does to summarise any file); by default
    /// such a file is refused, naming what is missing.
    pub allow_unknown_size: bool,
    /// AEDAT 4: the most bytes one packet may take, stored or decompressed; a packet that claims
    /// or expands to more is an error naming this limit. Default
    /// [`MAX_PACKET_BYTES`]; raise it for recordings of very large APS frames.
    pub max_packet_bytes: usize,
    /// Text: the most bytes one line may take (its line feed excluded); a longer line, or a file
    /// without a line feed, is an error naming the line. Default [`MAX_LINE_BYTES`].
    pub max_line_bytes: usize,
    /// Packets of a word stream (EVT 3.0 in ROS 2 `EventPacket`s): the most events one packet
    /// may hold; a packet that holds more is an error naming this limit. Default
    /// [`MAX_EVENTS_PER_PACKET`].
    pub max_events_per_packet: usize,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions {
            resolution: None,
            disorder: Disorder::default(),
            unknown_words: UnknownWords::default(),
            allow_unknown_size: false,
            max_packet_bytes: MAX_PACKET_BYTES,
            max_line_bytes: MAX_LINE_BYTES,
            max_events_per_packet: MAX_EVENTS_PER_PACKET,
        }
    }
}

impl ReadOptions {
    /// Options with a known sensor size and the strict defaults.
    pub fn with_resolution(width: u16, height: u16) -> Self {
        ReadOptions {
            resolution: Some(Resolution::new(width, height)),
            ..ReadOptions::default()
        }
    }
}

/// What a reader has seen so far. Every repair or skip a reader makes is counted here, so nothing
/// is changed silently.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ReadStats {
    /// Events delivered (or decoded and waiting to be delivered).
    pub events: u64,
    /// Of which ON (polarity +1).
    pub on_events: u64,
    /// Timestamp of the first event.
    pub first_t_ns: Option<i64>,
    /// Timestamp of the last event.
    pub last_t_ns: Option<i64>,
    /// Largest column seen.
    pub max_x: u16,
    /// Largest row seen.
    pub max_y: u16,
    /// Events restamped by [`Disorder::Clamp`].
    pub clamped_timestamps: u64,
    /// Events identical to the event just before them (same time, place and polarity). They are
    /// kept: real sensors do emit them.
    pub duplicate_events: u64,
    /// Sensor clock wraps undone (EVT 2.0: 34-bit µs; EVT 3.0: 24-bit µs; DAT: 32-bit µs).
    pub time_wraps: u64,
    /// External trigger words (counted, not delivered).
    pub triggers: u64,
    /// Words of defined types that carry no CD event: `OTHERS`, `CONTINUED`.
    pub skipped_words: u64,
    /// Words of undefined types skipped under [`UnknownWords::Skip`].
    pub unknown_words: u64,
    /// CD events met before the stream set its time base (the first `EVT_TIME_HIGH`) or, in
    /// EVT 3.0, its row; their time or place is unknown, so they are dropped and counted, as the
    /// Prophesee decoders do.
    pub events_without_time_base: u64,
    /// AEDAT 4 packets of streams other than the events read (APS frames, IMU, triggers),
    /// skipped without decompression.
    pub skipped_packets: u64,
    /// Text lines skipped: blank lines and `#` comments.
    pub lines_skipped: u64,
}

impl ReadStats {
    /// `last - first` timestamp in nanoseconds (0 with fewer than two events).
    pub fn duration_ns(&self) -> i64 {
        match (self.first_t_ns, self.last_t_ns) {
            (Some(a), Some(b)) => b.saturating_sub(a),
            _ => 0,
        }
    }
}

/// A streaming reader of events. Memory stays bounded whatever the file size: events are decoded
/// a buffer at a time, on demand.
///
/// When the file turns out to be bad part-way, every event decoded before the fault is delivered
/// first; the error comes on the next call, and after it the reader only returns `Ok(0)`.
pub trait EventReader {
    /// The file (or the name given to an in-memory source), as errors name it.
    fn source(&self) -> &Path;
    /// The sensor size every event is checked against.
    fn resolution(&self) -> Resolution;
    /// What has been decoded so far.
    fn stats(&self) -> &ReadStats;
    /// Appends up to `max` events to the columns of `out` (its header fields are left alone) and
    /// returns how many; `Ok(0)` means the end of the file (or `max == 0`).
    fn read_into(&mut self, out: &mut EventBatch, max: usize) -> Result<usize>;

    /// The next (up to) `max` events as a batch of this reader's size, `seq` 0, covering
    /// `[first t_ns, last t_ns + 1)`; `None` at the end of the file.
    fn next_chunk(&mut self, max: usize) -> Result<Option<EventBatch>> {
        let r = self.resolution();
        let mut batch = EventBatch::empty(r.width.into(), r.height.into(), 0, 0, 0);
        if self.read_into(&mut batch, max.max(1))? == 0 {
            return Ok(None);
        }
        set_interval(&mut batch);
        Ok(Some(batch))
    }

    /// An iterator over batches of up to `max` events, numbered by `seq` from 0.
    ///
    /// Each batch covers `[its first t_ns, its last t_ns + 1)`. Equal timestamps may straddle two
    /// batches, so two neighbouring intervals can share their boundary nanosecond; every event is
    /// in exactly one batch.
    fn into_chunks(self, max: usize) -> EventChunks<Self>
    where
        Self: Sized,
    {
        EventChunks {
            reader: self,
            max: max.max(1),
            seq: 0,
            done: false,
        }
    }
}

impl<R: EventReader + ?Sized> EventReader for Box<R> {
    fn source(&self) -> &Path {
        (**self).source()
    }
    fn resolution(&self) -> Resolution {
        (**self).resolution()
    }
    fn stats(&self) -> &ReadStats {
        (**self).stats()
    }
    fn read_into(&mut self, out: &mut EventBatch, max: usize) -> Result<usize> {
        (**self).read_into(out, max)
    }
}

fn set_interval(batch: &mut EventBatch) {
    if let (Some(&first), Some(&last)) = (batch.t_ns.first(), batch.t_ns.last()) {
        batch.t_start_ns = first;
        batch.t_end_ns = last.saturating_add(1);
    }
}

/// Batches of events from an [`EventReader`]; see [`EventReader::into_chunks`].
pub struct EventChunks<R> {
    reader: R,
    max: usize,
    seq: u64,
    done: bool,
}

impl<R: EventReader> EventChunks<R> {
    /// The reader, for its statistics.
    pub fn reader(&self) -> &R {
        &self.reader
    }
}

impl<R: EventReader> Iterator for EventChunks<R> {
    type Item = Result<EventBatch>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        match self.reader.next_chunk(self.max) {
            Ok(Some(mut b)) => {
                b.seq = self.seq;
                self.seq += 1;
                Some(Ok(b))
            }
            Ok(None) => {
                self.done = true;
                None
            }
            Err(e) => {
                self.done = true;
                Some(Err(e))
            }
        }
    }
}

/// How a reader ended under [`drain_checked`].
#[derive(Debug)]
pub struct Drained {
    /// Events delivered.
    pub events: u64,
    /// The error that stopped it, if it did not reach the end of its file.
    pub error: Option<FormatError>,
}

/// Drains `reader` in batches of `n` and checks what every reader promises, whatever its bytes:
/// each event inside the sensor, polarity ±1, time order, batches no longer than asked, and the
/// reader's count equal to what it delivered. A reader that stops with an error is fine (the
/// error is returned in [`Drained`]); a broken promise is `Err` naming it (a bug in the
/// reader). The mutation tests and the fuzz targets use it.
pub fn drain_checked(
    reader: &mut dyn EventReader,
    n: usize,
) -> std::result::Result<Drained, String> {
    let r = reader.resolution();
    let mut last = i64::MIN;
    let mut total = 0u64;
    let mut error = None;
    loop {
        let mut b = EventBatch::default();
        match reader.read_into(&mut b, n) {
            Ok(0) => break,
            Ok(k) => {
                if k > n || k != b.len() {
                    return Err(format!("read {k} of at most {n}, batch of {}", b.len()));
                }
                for i in 0..k {
                    let e = b.get(i);
                    if e.x >= r.width || e.y >= r.height {
                        return Err(format!("{e:?} outside {r}"));
                    }
                    if e.polarity != 1 && e.polarity != -1 {
                        return Err(format!("{e:?}: polarity"));
                    }
                    if e.t_ns < last {
                        return Err(format!("{e:?} before {last}"));
                    }
                    last = e.t_ns;
                }
                total += k as u64;
            }
            Err(e) => {
                error = Some(e);
                break;
            }
        }
    }
    if reader.stats().events != total {
        return Err(format!(
            "the reader counts {} events but delivered {total}",
            reader.stats().events
        ));
    }
    Ok(Drained {
        events: total,
        error,
    })
}

/// Reads a whole file into one batch. Convenient for tests and small files only: memory grows
/// with the file.
pub fn read_all(reader: &mut dyn EventReader) -> Result<EventBatch> {
    let r = reader.resolution();
    let mut batch = EventBatch::empty(r.width.into(), r.height.into(), 0, 0, 0);
    while reader.read_into(&mut batch, 1 << 16)? > 0 {}
    set_interval(&mut batch);
    Ok(batch)
}

/// The three [`EventReader`] accessors of a reader that keeps its [`Sink`] in a field `sink`.
macro_rules! sink_accessors {
    () => {
        fn source(&self) -> &std::path::Path {
            &self.sink.path
        }

        fn resolution(&self) -> crate::Resolution {
            self.sink.resolution
        }

        fn stats(&self) -> &crate::ReadStats {
            &self.sink.stats
        }
    };
}
pub(crate) use sink_accessors;

/// The checks and the delivery every decoded event goes through, shared by all event readers.
///
/// A decoder pushes events with [`Sink::emit`] until [`Sink::full`]; events of a multi-event word
/// that do not fit in the caller's request wait in an overflow queue for the next call.
/// Events a reader's fast path decodes at most before the sink checks them
/// ([`Sink::decode_blocks`]).
pub(crate) const BLOCK_EVENTS: usize = 4096;

pub(crate) struct Sink {
    pub(crate) path: PathBuf,
    /// Bounds: `x < width`, `y < height`. `u32` so that "unknown" (65,536) admits every `u16`.
    width: u32,
    height: u32,
    pub(crate) resolution: Resolution,
    /// The sensor size, when known.
    pub(crate) known: Option<Resolution>,
    disorder: Disorder,
    pub(crate) unknown_words: UnknownWords,
    pub(crate) stats: ReadStats,
    /// Time of the last event emitted (the disorder check).
    last_t_ns: Option<i64>,
    /// The last event counted by [`Sink::tally`] (the duplicate check across calls).
    last: Option<Event>,
    overflow: Vec<Event>,
    overflow_pos: usize,
    room: usize,
    pending: Option<FormatError>,
    finished: bool,
}

/// Bounds for a [`Sink`]: the sensor, or none (for [`crate::info`] on files of unknown size).
#[derive(Clone, Copy, Debug)]
pub(crate) enum Bounds {
    Sensor(Resolution),
    Unknown,
}

impl Sink {
    pub(crate) fn new(path: PathBuf, bounds: Bounds, opts: &ReadOptions) -> Self {
        let (width, height, resolution, known) = match bounds {
            Bounds::Sensor(r) => (u32::from(r.width), u32::from(r.height), r, Some(r)),
            Bounds::Unknown => (1 << 16, 1 << 16, Resolution::new(u16::MAX, u16::MAX), None),
        };
        Sink {
            path,
            width,
            height,
            resolution,
            known,
            disorder: opts.disorder,
            unknown_words: opts.unknown_words,
            stats: ReadStats::default(),
            last_t_ns: None,
            last: None,
            overflow: Vec::new(),
            overflow_pos: 0,
            room: 0,
            pending: None,
            finished: false,
        }
    }

    /// No more room in the caller's request: the decoder should stop at the next word boundary.
    #[inline]
    pub(crate) fn full(&self) -> bool {
        self.room == 0
    }

    /// The input is exhausted without error.
    pub(crate) fn finish(&mut self) {
        self.finished = true;
    }

    /// Checks one event and delivers it (or queues it when the request is full). The errors are
    /// built out of line ([`Sink::out_of_bounds`], [`Sink::unsorted`]) and the statistics are
    /// counted afterwards over the whole run ([`Sink::tally`]): the common path is three compares
    /// and four pushes, small enough to inline into every decoder loop.
    #[inline(always)]
    pub(crate) fn emit(
        &mut self,
        out: &mut EventBatch,
        t_ns: i64,
        x: u32,
        y: u32,
        on: bool,
        at: Location,
    ) -> Result<()> {
        if x >= self.width || y >= self.height {
            return Err(self.out_of_bounds(at, x, y));
        }
        let mut t_ns = t_ns;
        if let Some(last) = self.last_t_ns
            && t_ns < last
        {
            match self.disorder {
                Disorder::Error => return Err(self.unsorted(at, t_ns, last)),
                Disorder::Clamp => {
                    t_ns = last;
                    self.stats.clamped_timestamps += 1;
                }
            }
        }
        self.last_t_ns = Some(t_ns);
        // Bounds were checked above, so both fit in u16.
        let e = Event {
            t_ns,
            x: x as u16,
            y: y as u16,
            polarity: if on { 1 } else { -1 },
        };
        if self.room > 0 {
            out.push(e);
            self.room -= 1;
        } else {
            self.overflow.push(e);
        }
        Ok(())
    }

    /// The sensor size events are checked against, `(width, height)` (65,536 when unknown).
    #[inline]
    pub(crate) fn bounds(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// How many more events the caller's request takes.
    #[inline]
    pub(crate) fn room(&self) -> usize {
        self.room
    }

    /// A binary reader's decode loop over the whole units of `UNIT` bytes (words, records) of
    /// `bytes`, which start at file offset `offset`, until this sink is full; returns the bytes
    /// consumed.
    ///
    /// `fast(state, bytes, out, max)` decodes up to `max` events (at most [`BLOCK_EVENTS`])
    /// straight into `out` and returns the bytes it used; [`Sink::accept_block`] then checks the
    /// block in column passes. A block refused is taken back (events and `state`) and, like every
    /// unit the fast path leaves, goes through `checked(state, bytes, offset, sink, out)`, which
    /// emits event by event and names the fault or repairs it.
    pub(crate) fn decode_blocks<S: Copy, const UNIT: usize>(
        &mut self,
        bytes: &[u8],
        offset: u64,
        state: &mut S,
        out: &mut EventBatch,
        mut fast: impl FnMut(&mut S, &[u8], &mut EventBatch, usize) -> usize,
        mut checked: impl FnMut(&mut S, &[u8], u64, &mut Sink, &mut EventBatch) -> Result<usize>,
    ) -> Result<usize> {
        let whole = bytes.len() - bytes.len() % UNIT;
        let mut consumed = 0usize;
        while consumed < whole && !self.full() {
            let (saved, start) = (*state, out.len());
            let max = self.room().min(BLOCK_EVENTS);
            let n = fast(state, &bytes[consumed..whole], out, max);
            if n > 0 {
                if self.accept_block(out, start) {
                    consumed += n;
                    continue;
                }
                *state = saved;
                out.truncate(start);
            }
            let end = consumed + n.max(UNIT);
            let at = offset + consumed as u64;
            consumed += checked(state, &bytes[consumed..end], at, self, out)?;
        }
        Ok(consumed)
    }

    /// Accepts the events a decoder appended to `out[start..]` in one go (no more than
    /// [`Sink::room`]), when every one is inside the sensor and in time order (after the last
    /// event emitted): branch-free passes over the columns, which vectorise. Returns `false`,
    /// changing nothing, when one is not (or there are too many): the decoder then truncates `out`
    /// back to `start` and emits the events one by one, which names the fault or repairs it.
    pub(crate) fn accept_block(&mut self, out: &EventBatch, start: usize) -> bool {
        let (t, x, y) = (&out.t_ns[start..], &out.x[start..], &out.y[start..]);
        let n = t.len();
        if n == 0 {
            return true;
        }
        if n > self.room {
            return false;
        }
        let (x_max, y_max, steps_back) = neuspike_simd::dispatch(
            #[inline(always)]
            || {
                (
                    x.iter().fold(0u16, |m, &v| m.max(v)),
                    y.iter().fold(0u16, |m, &v| m.max(v)),
                    t.iter()
                        .zip(&t[1..])
                        .fold(false, |bad, (a, b)| bad | (b < a)),
                )
            },
        );
        let unsorted = self.last_t_ns.is_some_and(|last| t[0] < last) | steps_back;
        if u32::from(x_max) >= self.width || u32::from(y_max) >= self.height || unsorted {
            return false;
        }
        self.last_t_ns = Some(t[n - 1]);
        self.room -= n;
        true
    }

    /// Counts the events a decoder emitted, in emission order: those delivered into
    /// `out[from..]` (column passes, which vectorise), then those queued in
    /// `overflow[overflow_from..]`.
    fn tally(&mut self, out: &EventBatch, from: usize, overflow_from: usize) {
        let s = &mut self.stats;
        let mut prev = self.last;
        if from < out.len() {
            let (t, x, y, p) = (
                &out.t_ns[from..],
                &out.x[from..],
                &out.y[from..],
                &out.polarity[from..],
            );
            let first = out.get(from);
            s.first_t_ns.get_or_insert(first.t_ns);
            s.duplicate_events += u64::from(prev == Some(first));
            s.events += t.len() as u64;
            // Branch-free column passes, compiled for the widest vectors the CPU has; the
            // polarity count in u32 blocks (a block of 2^16 events cannot overflow it).
            let (on, max_x, max_y, duplicates) = neuspike_simd::dispatch(
                #[inline(always)]
                || {
                    let on = p
                        .chunks(1 << 16)
                        .map(|b| u64::from(b.iter().map(|&p| u32::from(p > 0)).sum::<u32>()))
                        .sum::<u64>();
                    let max_x = x.iter().copied().fold(0, u16::max);
                    let max_y = y.iter().copied().fold(0, u16::max);
                    // Each event against the one before it, all four columns, in blocks.
                    let mut duplicates = 0u64;
                    let mut i = 1;
                    while i < t.len() {
                        let end = t.len().min(i + (1 << 16));
                        let (a, b) = (i..end, i - 1..end - 1);
                        let same = (t[a.clone()].iter().zip(&t[b.clone()]))
                            .zip(x[a.clone()].iter().zip(&x[b.clone()]))
                            .zip(y[a.clone()].iter().zip(&y[b.clone()]))
                            .zip(p[a].iter().zip(&p[b]))
                            .map(|(((t, x), y), p)| {
                                u32::from((t.0 == t.1) & (x.0 == x.1) & (y.0 == y.1) & (p.0 == p.1))
                            })
                            .sum::<u32>();
                        duplicates += u64::from(same);
                        i = end;
                    }
                    (on, max_x, max_y, duplicates)
                },
            );
            s.on_events += on;
            s.max_x = s.max_x.max(max_x);
            s.max_y = s.max_y.max(max_y);
            s.duplicate_events += duplicates;
            prev = Some(out.get(out.len() - 1));
        }
        for &e in &self.overflow[overflow_from..] {
            s.first_t_ns.get_or_insert(e.t_ns);
            s.duplicate_events += u64::from(prev == Some(e));
            s.events += 1;
            s.on_events += u64::from(e.polarity > 0);
            s.max_x = s.max_x.max(e.x);
            s.max_y = s.max_y.max(e.y);
            prev = Some(e);
        }
        self.last = prev;
        if let Some(e) = prev {
            s.last_t_ns = Some(e.t_ns);
        }
    }

    #[cold]
    #[inline(never)]
    fn out_of_bounds(&self, at: Location, x: u32, y: u32) -> FormatError {
        FormatError::OutOfBounds {
            path: self.path.clone(),
            at,
            x,
            y,
            width: self.width,
            height: self.height,
        }
    }

    #[cold]
    #[inline(never)]
    fn unsorted(&self, at: Location, t_ns: i64, previous_t_ns: i64) -> FormatError {
        FormatError::Unsorted {
            path: self.path.clone(),
            at,
            t_ns,
            previous_t_ns,
        }
    }

    /// Counts or rejects a word of an undefined type.
    pub(crate) fn unknown_word(
        &mut self,
        offset: u64,
        format: &'static str,
        word_type: u8,
        value: u32,
    ) -> Result<()> {
        match self.unknown_words {
            UnknownWords::Error => Err(FormatError::UnknownWord {
                path: self.path.clone(),
                offset,
                format,
                word_type,
                value,
            }),
            UnknownWords::Skip => {
                self.stats.unknown_words += 1;
                Ok(())
            }
        }
    }

    /// One `read_into` call: delivers queued events, then a pending error, then runs `decode`
    /// (which must emit until [`Sink::full`] or call [`Sink::finish`] at the end of its input).
    /// An error with events already delivered in this call is kept for the next call.
    pub(crate) fn read_with<F>(
        &mut self,
        out: &mut EventBatch,
        max: usize,
        decode: F,
    ) -> Result<usize>
    where
        F: FnOnce(&mut Sink, &mut EventBatch) -> Result<()>,
    {
        let start = out.len();
        self.room = max;
        while self.room > 0 && self.overflow_pos < self.overflow.len() {
            out.push(self.overflow[self.overflow_pos]);
            self.overflow_pos += 1;
            self.room -= 1;
        }
        if self.overflow_pos == self.overflow.len() {
            self.overflow.clear();
            self.overflow_pos = 0;
        }
        if self.room > 0 {
            if let Some(e) = self.pending.take() {
                if out.len() > start {
                    self.pending = Some(e);
                } else {
                    self.finished = true;
                    return Err(e);
                }
            } else if !self.finished {
                let (from, overflow_from) = (out.len(), self.overflow.len());
                let decoded = decode(self, out);
                self.tally(out, from, overflow_from);
                if let Err(e) = decoded {
                    self.finished = true;
                    if out.len() > start || !self.overflow.is_empty() {
                        self.pending = Some(e);
                    } else {
                        return Err(e);
                    }
                }
            }
        }
        self.room = 0;
        Ok(out.len() - start)
    }
}

/// Support for the binary readers' tests that hold the fast path to the checked one.
#[cfg(test)]
pub(crate) mod fast_vs_checked {
    use super::*;
    use proptest::prelude::*;

    /// What a decode gave: the events, the statistics and the error that ended it, if any.
    pub(crate) type Decoded = (EventBatch, ReadStats, Option<String>);

    /// Feeds `bytes` to `decode` (the bytes from the current position, their offset, the sink
    /// and the batch; returns the bytes consumed) on a 40x30 sensor, in requests of `max`
    /// events and at most `piece` bytes at a time (buffer boundaries), until the input ends
    /// (a call that consumes nothing ends it: less than a word is left) or an error ends it.
    pub(crate) fn decode_all(
        bytes: &[u8],
        max: usize,
        piece: usize,
        opts: &ReadOptions,
        mut decode: impl FnMut(&[u8], u64, &mut Sink, &mut EventBatch) -> Result<usize>,
    ) -> Decoded {
        let mut sink = Sink::new("mem".into(), Bounds::Sensor(Resolution::new(40, 30)), opts);
        let mut out = EventBatch::default();
        let mut pos = 0usize;
        loop {
            let got = sink.read_with(&mut out, max, |sink, out| {
                while !sink.full() {
                    let end = bytes.len().min(pos + piece);
                    let used = if pos < end {
                        decode(&bytes[pos..end], pos as u64, sink, out)?
                    } else {
                        0
                    };
                    if used == 0 {
                        sink.finish();
                        return Ok(());
                    }
                    pos += used;
                }
                Ok(())
            });
            match got {
                Ok(0) => return (out, sink.stats.clone(), None),
                Ok(_) => {}
                Err(e) => return (out, sink.stats.clone(), Some(e.to_string())),
            }
        }
    }

    /// Options: out-of-order times clamped or refused, unknown words skipped or refused.
    pub(crate) fn options(clamp: bool, skip_unknown: bool) -> ReadOptions {
        ReadOptions {
            disorder: if clamp {
                Disorder::Clamp
            } else {
                Disorder::Error
            },
            unknown_words: if skip_unknown {
                UnknownWords::Skip
            } else {
                UnknownWords::Error
            },
            ..ReadOptions::default()
        }
    }

    /// The two decodes gave the same events, statistics and error.
    pub(crate) fn assert_same(fast: &Decoded, checked: &Decoded) -> Result<(), TestCaseError> {
        prop_assert_eq!(&fast.0.t_ns, &checked.0.t_ns);
        prop_assert_eq!(&fast.0.x, &checked.0.x);
        prop_assert_eq!(&fast.0.y, &checked.0.y);
        prop_assert_eq!(&fast.0.polarity, &checked.0.polarity);
        prop_assert_eq!(&fast.1, &checked.1);
        prop_assert_eq!(&fast.2, &checked.2);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sink(disorder: Disorder) -> Sink {
        Sink::new(
            PathBuf::from("mem"),
            Bounds::Sensor(Resolution::new(4, 3)),
            &ReadOptions {
                disorder,
                ..ReadOptions::default()
            },
        )
    }

    #[test]
    fn clamp_counts_and_error_names_both_times() {
        let mut s = sink(Disorder::Clamp);
        let mut out = EventBatch::default();
        s.room = 10;
        s.emit(&mut out, 10, 0, 0, true, Location::Byte(0)).unwrap();
        s.emit(&mut out, 5, 1, 0, false, Location::Byte(4)).unwrap();
        assert_eq!(out.t_ns, vec![10, 10]);
        assert_eq!(s.stats.clamped_timestamps, 1);

        let mut s = sink(Disorder::Error);
        s.room = 10;
        s.emit(&mut out, 10, 0, 0, true, Location::Byte(0)).unwrap();
        let e = s
            .emit(&mut out, 5, 1, 0, false, Location::Line(7))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 7") && e.contains("5 ns") && e.contains("10 ns"),
            "{e}"
        );
    }

    /// The column passes of `tally` against a plain count, over more events than one of their
    /// blocks (2^16), with duplicates on both sides of the block boundary and across calls.
    #[test]
    fn tally_agrees_with_a_plain_count_across_blocks_and_calls() {
        let mut out = EventBatch::default();
        let mut state = 7u64;
        for i in 0..150_000u64 {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            let r = state >> 33;
            let e = Event {
                t_ns: (i / 3) as i64,
                x: (r % 4) as u16,
                y: ((r >> 2) % 3) as u16,
                polarity: if r >> 4 & 1 == 1 { 1 } else { -1 },
            };
            // Runs of repeats, one straddling the first block boundary.
            let repeat = (i % 7 == 0 || (65_530..65_540).contains(&i)) && i > 0;
            out.push(if repeat { out.get(out.len() - 1) } else { e });
        }
        let events: Vec<Event> = (0..out.len()).map(|i| out.get(i)).collect();
        let mut s = sink(Disorder::Error);
        s.tally(&out, 0, 0);
        // The rest as a second call: the pair across the calls counts too.
        let mut more = EventBatch::default();
        more.push(events[events.len() - 1]);
        more.push(events[0]);
        s.tally(&more, 0, 0);
        let all: Vec<Event> = events
            .iter()
            .copied()
            .chain([events[events.len() - 1], events[0]])
            .collect();
        let st = &s.stats;
        assert_eq!(st.events, all.len() as u64);
        assert_eq!(
            st.on_events,
            all.iter().filter(|e| e.polarity > 0).count() as u64
        );
        assert_eq!(st.max_x, all.iter().map(|e| e.x).max().unwrap());
        assert_eq!(st.max_y, all.iter().map(|e| e.y).max().unwrap());
        let dups = all.windows(2).filter(|p| p[0] == p[1]).count() as u64;
        assert!(dups > 150_000 / 7);
        assert_eq!(st.duplicate_events, dups);
    }

    #[test]
    fn overflow_is_delivered_before_a_pending_error() {
        let mut s = sink(Disorder::Error);
        let mut out = EventBatch::default();
        let n = s
            .read_with(&mut out, 2, |s, out| {
                for x in 0..3 {
                    s.emit(out, 1, x, 0, true, Location::Byte(0))?;
                }
                s.emit(out, 1, 9, 0, true, Location::Byte(8))
            })
            .unwrap();
        assert_eq!(n, 2);
        let n = s.read_with(&mut out, 2, |_, _| unreachable!()).unwrap();
        assert_eq!(n, 1);
        let e = s.read_with(&mut out, 2, |_, _| unreachable!()).unwrap_err();
        assert!(e.to_string().contains("(9, 0)"), "{e}");
        assert_eq!(s.read_with(&mut out, 2, |_, _| unreachable!()).unwrap(), 0);
    }
}
