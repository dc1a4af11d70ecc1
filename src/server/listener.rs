//! Accepting and serving connections (HTTP/1.1 on hyper), with the limits that keep a few
//! clients from holding the server:
//!
//! - at most `max_connections` connections open: past that, `accept` waits (new connections
//!   queue in the kernel's backlog) until one closes, so a flood cannot exhaust descriptors;
//! - at most `per_client` connections from one IP address: a further one is answered `503`
//!   and closed at once, so one client cannot fill `max_connections` for everyone else;
//! - a connection that sends part of a request head must complete it within `header_timeout`
//!   of its first byte (slowloris), or it is closed;
//! - a connection with no request in flight and no bytes moving for `idle_timeout` (an idle
//!   keep-alive connection, or one that never sends anything) is closed.
//!
//! hyper's own `header_read_timeout` is not used: its timer starts whenever hyper waits for a
//! request head, including the wait between keep-alive requests, so it would close idle
//! connections after the (short) header timeout instead of the (longer) idle timeout. Both
//! are kept here instead, from what the connection's reads and writes and its service calls
//! see (`Activity`).
//!
//! Connections are HTTP/1.1 with half-close support: a client that sends its requests and then
//! shuts its write side (pipelining, then `shutdown(SHUT_WR)`) gets every response before the
//! server closes.
//!
//! A connection starts on the wire-level fast path ([`wire`]), which answers `GET`s of
//! in-memory blobs from the connection's bytes (`fast::FastPath::wire_step`) and keeps the same
//! two timeouts itself; at the first request it does not answer, hyper takes the connection
//! for the rest of its life, starting with the bytes already read.
//!
//! The server runs one `serve` per serving thread (`--threads`), each on its own
//! single-threaded runtime with its own listening socket (`SO_REUSEPORT`: the kernel spreads
//! new connections over them); the limits (`Shared`) are counted across all of them.

use std::collections::HashMap;
use std::io;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use axum::extract::ConnectInfo;
use bytes::{Buf, Bytes, BytesMut};
use hyper_util::rt::TokioIo;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore, watch};
use tower::Service;

use super::fast::{FastPath, Step};
use super::http::Peer;
use super::metrics::Metrics;

/// The connection limits (from `Config`).
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    pub max_connections: usize,
    /// 0 = no per-client limit.
    pub per_client: usize,
    pub header_timeout: Duration,
    pub idle_timeout: Duration,
}

/// What every serving thread's `serve` shares: the connection count under `max_connections`,
/// the connections per client address and, where connections are steered to the thread of
/// their CPU, each thread's open connections and inbox (`Balance`).
pub struct Shared {
    permits: Arc<Semaphore>,
    clients: Arc<Clients>,
    balance: Option<Balance>,
}

impl Shared {
    /// Limits only: each thread keeps what it accepts (the kernel's hash spreads connections).
    #[must_use]
    pub fn new(limits: &Limits) -> Self {
        Self {
            permits: Arc::new(Semaphore::new(limits.max_connections)),
            clients: Arc::new(Clients::default()),
            balance: None,
        }
    }

    /// For `threads` serving threads whose sockets take the connections of their own CPU
    /// (`affinity`): all of one CPU's new connections reach one thread (a network card with
    /// one queue delivers every connection on one CPU; on loopback, a client connects from
    /// the CPU it runs on), and a connection never changes threads by itself. So each thread
    /// watches the requests every thread answered in the last `BALANCE_PERIOD`: one that
    /// answered more than twice the least busy one's (and at least `BALANCE_MIN_REQUESTS`)
    /// while holding at least two connections more hands half the difference to it, each
    /// connection at its next idle moment (no request in flight, no byte of the next read).
    /// Only connections on the wire-level fast path can move that way (hyper keeps the ones it
    /// serves), so at accept too a thread holding `ACCEPT_SLACK` connections more than twice
    /// the least loaded thread's passes the new one to it: a burst from one CPU (a client's
    /// connections, opened together) stays together, a lasting skew (a network card with one
    /// queue) stays within about 2:1. Returns the threads' inboxes, one for each `serve`.
    #[must_use]
    pub fn balanced(limits: &Limits, threads: usize) -> (Self, Vec<Inbox>) {
        let (senders, inboxes): (Vec<_>, Vec<_>) =
            (0..threads).map(|_| tokio::sync::mpsc::unbounded_channel()).unzip();
        let balance = Balance { threads: (0..threads).map(|_| ThreadLoad::default()).collect(), senders };
        (Self { balance: Some(balance), ..Self::new(limits) }, inboxes.into_iter().map(Inbox).collect())
    }
}

/// How often a thread compares its load with the others' (`Shared::balanced`).
const BALANCE_PERIOD: Duration = Duration::from_millis(100);
/// Requests a thread must have answered in a `BALANCE_PERIOD` before it hands connections on.
const BALANCE_MIN_REQUESTS: u64 = 500;
/// Connections a thread may hold beyond twice the least loaded thread's before it passes new
/// ones on at accept.
const ACCEPT_SLACK: usize = 64;

impl Shared {
    /// Counts a request serving thread `thread` answered (`balance_loop` compares the counts).
    fn count_answered(&self, thread: usize) {
        if let Some(l) = self.balance.as_ref().and_then(|b| b.threads.get(thread)) {
            l.answered.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// A serving thread's connections handed over by other threads.
pub struct Inbox(tokio::sync::mpsc::UnboundedReceiver<Handed>);

/// A connection admitted by one thread, to be served by another.
struct Handed {
    stream: std::net::TcpStream,
    addr: SocketAddr,
    slots: Slots,
}

/// What a connection holds while it lives: its place under `max_connections`, under its
/// client's cap, in `terrastream_connections_open` and (with `Shared::balanced`) in its
/// thread's count.
struct Slots {
    _permit: OwnedSemaphorePermit,
    _client: ClientSlot,
    open: OpenGauge,
    thread: Option<ThreadGauge>,
}

/// The serving threads' loads and inboxes.
struct Balance {
    threads: Box<[ThreadLoad]>,
    senders: Vec<tokio::sync::mpsc::UnboundedSender<Handed>>,
}

/// One serving thread's counters, on a cache line of its own (each is written by its thread
/// on every request).
#[derive(Default)]
#[repr(align(128))]
struct ThreadLoad {
    /// Connections it serves.
    open: AtomicUsize,
    /// Requests it answered (on the wire-level fast path and through hyper).
    answered: AtomicU64,
    /// Connections it should hand to thread `shed_to` at their next idle moment.
    shed: AtomicUsize,
    shed_to: AtomicUsize,
}

/// A connection's place in its serving thread's `ThreadLoad`, given back when dropped.
struct ThreadGauge {
    shared: Arc<Shared>,
    thread: usize,
}

impl ThreadGauge {
    fn new(shared: &Arc<Shared>, thread: usize) -> Option<Self> {
        shared.balance.as_ref()?.threads.get(thread)?.open.fetch_add(1, Ordering::Relaxed);
        Some(Self { shared: shared.clone(), thread })
    }

    fn load(&self) -> Option<&ThreadLoad> {
        self.shared.balance.as_ref()?.threads.get(self.thread)
    }

    /// Counts a request answered.
    fn answered(&self) {
        self.shared.count_answered(self.thread);
    }

    /// The thread an idle connection of this one should move to now, if any (taking one from
    /// the thread's `shed`).
    fn take_move(&self) -> Option<usize> {
        let l = self.load()?;
        if l.shed.load(Ordering::Relaxed) == 0 {
            return None;
        }
        l.shed.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| n.checked_sub(1)).ok()?;
        Some(l.shed_to.load(Ordering::Relaxed))
    }
}

impl Drop for ThreadGauge {
    fn drop(&mut self) {
        if let Some(l) = self.load() {
            l.open.fetch_sub(1, Ordering::Relaxed);
        }
    }
}

/// The thread that serves a connection thread `me` accepts, given each thread's open
/// connections: `me`, unless it holds at least `slack` more than twice the least loaded
/// thread's (the first of equals), which then gets it.
fn accept_target(me: usize, open: impl IntoIterator<Item = usize>, slack: usize) -> usize {
    let (mut mine, mut least) = (None, None::<(usize, usize)>);
    for (i, n) in open.into_iter().enumerate() {
        if i == me {
            mine = Some(n);
        }
        if least.is_none_or(|(_, m)| n < m) {
            least = Some((i, n));
        }
    }
    match (mine, least) {
        (Some(mine), Some((j, n))) if j != me && mine >= n.saturating_mul(2).saturating_add(slack) => j,
        _ => me,
    }
}

/// What thread `me` should shed, from each thread's requests answered in the last period and
/// open connections: `(count, to)` toward the thread that answered fewest (the first of
/// equals), when `me` answered at least `min` and more than twice as many and holds at least
/// two connections more; else nothing.
fn shed_plan(me: usize, answered: &[u64], open: &[usize], min: u64) -> Option<(usize, usize)> {
    let (&mine, &mine_open) = (answered.get(me)?, open.get(me)?);
    let (j, &least) = answered.iter().enumerate().filter(|&(i, _)| i != me).min_by_key(|&(i, &n)| (n, i))?;
    let theirs = *open.get(j)?;
    (mine >= min && mine > least.saturating_mul(2) && mine_open >= theirs + 2)
        .then(|| ((mine_open - theirs) / 2, j))
}

/// Thread `me`'s balancing loop (`Shared::balanced`): every `BALANCE_PERIOD`, sets how many of
/// its connections move, and where (`shed_plan`).
async fn balance_loop(shared: Arc<Shared>, me: usize, mut stop: watch::Receiver<bool>) {
    let Some(b) = shared.balance.as_ref() else { return };
    let snapshot = || b.threads.iter().map(|t| t.answered.load(Ordering::Relaxed)).collect::<Vec<_>>();
    let mut before = snapshot();
    let mut tick = tokio::time::interval(BALANCE_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = stop.wait_for(|v| *v) => return,
        }
        let now = snapshot();
        let answered: Vec<u64> = now.iter().zip(&before).map(|(a, b)| a.wrapping_sub(*b)).collect();
        before = now;
        let open: Vec<usize> = b.threads.iter().map(|t| t.open.load(Ordering::Relaxed)).collect();
        let Some(mine) = b.threads.get(me) else { return };
        match shed_plan(me, &answered, &open, BALANCE_MIN_REQUESTS) {
            Some((n, to)) => {
                tracing::debug!(
                    thread = me,
                    to,
                    connections = n,
                    ?answered,
                    ?open,
                    "moving idle connections to a less busy thread"
                );
                mine.shed_to.store(to, Ordering::Relaxed);
                mine.shed.store(n, Ordering::Relaxed);
            }
            None => mine.shed.store(0, Ordering::Relaxed),
        }
    }
}

/// Open connections per client address.
#[derive(Default)]
struct Clients {
    open: Mutex<HashMap<IpAddr, usize>>,
}

/// One connection's place in `Clients`, given back when dropped.
struct ClientSlot {
    clients: Arc<Clients>,
    ip: IpAddr,
}

impl Clients {
    /// A slot for `ip`, or `None` when it already holds `cap` connections (0 = no cap).
    fn admit(self: &Arc<Self>, ip: IpAddr, cap: usize) -> Option<ClientSlot> {
        let mut open = self.open.lock().ok()?;
        let n = open.entry(ip).or_insert(0);
        if cap > 0 && *n >= cap {
            return None;
        }
        *n += 1;
        Some(ClientSlot { clients: self.clone(), ip })
    }
}

impl Drop for ClientSlot {
    fn drop(&mut self) {
        if let Ok(mut open) = self.clients.open.lock()
            && let Some(n) = open.get_mut(&self.ip)
        {
            *n -= 1;
            if *n == 0 {
                open.remove(&self.ip);
            }
        }
    }
}

/// `head_since` when no request head is being read.
const NO_HEAD: u64 = u64::MAX;

/// What a connection is doing, for its timeouts: times are milliseconds since `epoch`.
struct Activity {
    epoch: Instant,
    /// Last read or write of at least one byte (or the connection's start).
    last: AtomicU64,
    /// When the first byte of a request head arrived while no request was in flight; `NO_HEAD`
    /// when none is being read.
    head_since: AtomicU64,
    /// Requests handed to the service and not answered yet.
    busy: AtomicUsize,
    /// Wakes the watchdog when a head starts (its deadline moves earlier).
    wake: Notify,
}

/// Why the watchdog closed a connection.
#[derive(Debug, Clone, Copy)]
enum Expired {
    Idle,
    Header,
}

impl Activity {
    fn new() -> Self {
        Self {
            epoch: Instant::now(),
            last: AtomicU64::new(0),
            head_since: AtomicU64::new(NO_HEAD),
            busy: AtomicUsize::new(0),
            wake: Notify::new(),
        }
    }

    fn now(&self) -> u64 {
        u64::try_from(self.epoch.elapsed().as_millis()).unwrap_or(u64::MAX - 1)
    }

    fn read(&self) {
        let now = self.now();
        self.last.store(now, Ordering::Relaxed);
        if self.busy.load(Ordering::Acquire) == 0
            && self.head_since.compare_exchange(NO_HEAD, now, Ordering::AcqRel, Ordering::Relaxed).is_ok()
        {
            self.wake.notify_one();
        }
    }

    fn wrote(&self) {
        self.last.store(self.now(), Ordering::Relaxed);
    }

    fn request_started(&self) {
        self.busy.fetch_add(1, Ordering::AcqRel);
        self.head_since.store(NO_HEAD, Ordering::Release);
        self.last.store(self.now(), Ordering::Relaxed);
    }

    fn request_done(&self) {
        self.last.store(self.now(), Ordering::Relaxed);
        self.busy.fetch_sub(1, Ordering::AcqRel);
    }

    /// Completes when the connection has been idle, or reading one request head, too long.
    async fn expired(&self, limits: Limits) -> Expired {
        let ms = |d: Duration| u64::try_from(d.as_millis()).unwrap_or(u64::MAX / 2);
        let (header, idle) = (ms(limits.header_timeout), ms(limits.idle_timeout));
        loop {
            let now = self.now();
            let head = self.head_since.load(Ordering::Acquire);
            let deadline = if self.busy.load(Ordering::Acquire) > 0 {
                // A request in flight is bounded by the request timeout (or, for uploads, by
                // the body limit); check again later.
                now + idle
            } else if head != NO_HEAD {
                if now >= head + header {
                    return Expired::Header;
                }
                head + header
            } else {
                let last = self.last.load(Ordering::Relaxed);
                if now >= last + idle {
                    return Expired::Idle;
                }
                last + idle
            };
            let sleep = tokio::time::sleep(Duration::from_millis(deadline.saturating_sub(now).max(1)));
            tokio::select! {
                () = sleep => {}
                () = self.wake.notified() => {}
            }
        }
    }
}

/// A connection: the stream, its slots in the limits, and its activity.
struct Conn {
    stream: TcpStream,
    activity: Arc<Activity>,
    slots: Slots,
}

/// Counts a connection in `terrastream_connections_open` while it lives.
struct OpenGauge(Arc<Metrics>);
impl Drop for OpenGauge {
    fn drop(&mut self) {
        self.0.connections_open.fetch_sub(1, Ordering::Relaxed);
    }
}

impl AsyncRead for Conn {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        let r = Pin::new(&mut this.stream).poll_read(cx, buf);
        if matches!(r, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            this.activity.read();
        }
        r
    }
}

impl AsyncWrite for Conn {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let r = Pin::new(&mut this.stream).poll_write(cx, buf);
        if matches!(r, Poll::Ready(Ok(n)) if n > 0) {
            this.activity.wrote();
        }
        r
    }
    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_flush(cx)
    }
    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_shutdown(cx)
    }
    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let r = Pin::new(&mut this.stream).poll_write_vectored(cx, bufs);
        if matches!(r, Poll::Ready(Ok(n)) if n > 0) {
            this.activity.wrote();
        }
        r
    }
    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

/// A connection handed to hyper: the bytes the wire-level fast path already read come first.
struct Rewind {
    pre: Bytes,
    conn: Conn,
}

impl AsyncRead for Rewind {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        if this.pre.is_empty() {
            return Pin::new(&mut this.conn).poll_read(cx, buf);
        }
        let n = this.pre.len().min(buf.remaining());
        buf.put_slice(&this.pre[..n]);
        this.pre.advance(n);
        Poll::Ready(Ok(()))
    }
}

impl AsyncWrite for Rewind {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.get_mut().conn).poll_write(cx, buf)
    }
    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().conn).poll_flush(cx)
    }
    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().conn).poll_shutdown(cx)
    }
    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.get_mut().conn).poll_write_vectored(cx, bufs)
    }
    fn is_write_vectored(&self) -> bool {
        self.conn.is_write_vectored()
    }
}

/// Bytes a connection's read buffer grows by at a time on the wire-level fast path.
const WIRE_READ: usize = 4096;

/// The wire-level fast path of one connection: answers the requests `front` answers, in order
/// (pipelined ones too), until the connection ends (`Closed`: by the client, by a timeout,
/// after `Connection: close`, on an error or at shutdown, with no request in flight), a
/// request comes that `front` does not answer (`Hyper`: the bytes read and not answered, from
/// that request's first byte), or, idle, it is to move to another serving thread (`Move`:
/// `thread` says so, `ThreadGauge::take_move`). Keeps the idle and header timeouts as the
/// watchdog does for hyper, lazily: one timer per connection, moved only when it fires early.
async fn wire(
    stream: &mut TcpStream,
    front: &FastPath,
    limits: Limits,
    thread: Option<&ThreadGauge>,
    stop: &mut watch::Receiver<bool>,
) -> WireEnd {
    let mut buf = BytesMut::with_capacity(WIRE_READ);
    let mut out = Vec::with_capacity(512);
    let mut last = Instant::now();
    // When the first byte of the head being read arrived.
    let mut head_since: Option<Instant> = None;
    let timer = tokio::time::sleep(limits.idle_timeout);
    let mut timer = std::pin::pin!(timer);
    loop {
        while !buf.is_empty() {
            match front.wire_step(&buf, &mut out) {
                Step::NeedMore => break,
                Step::Handoff => return WireEnd::Hyper(buf),
                Step::Answer { consumed, body, close } => {
                    if write_two(stream, &out, &body, limits.idle_timeout).await.is_err() {
                        return WireEnd::Closed;
                    }
                    if let Some(t) = thread {
                        t.answered();
                    }
                    buf.advance(consumed);
                    last = Instant::now();
                    head_since = None;
                    if close {
                        let _ = stream.shutdown().await;
                        return WireEnd::Closed;
                    }
                }
            }
        }
        if buf.is_empty() {
            head_since = None;
            if let Some(to) = thread.and_then(ThreadGauge::take_move) {
                return WireEnd::Move(to);
            }
        } else if head_since.is_none() {
            let now = Instant::now();
            head_since = Some(now);
            let deadline = tokio::time::Instant::from_std(now + limits.header_timeout);
            if timer.deadline() > deadline {
                timer.as_mut().reset(deadline);
            }
        }
        // A partial head here is under `fast::WIRE_MAX_HEAD` (else `wire_step` handed it off), so the
        // buffer stays under that plus WIRE_READ.
        if buf.capacity() - buf.len() < WIRE_READ / 4 {
            buf.reserve(WIRE_READ);
        }
        tokio::select! {
            biased;
            r = stream.read_buf(&mut buf) => match r {
                // The client closed (a partial head is dropped, as hyper does) or the
                // connection failed: every complete request before was answered.
                Ok(0) | Err(_) => return WireEnd::Closed,
                Ok(_) => last = Instant::now(),
            },
            () = timer.as_mut() => {
                let now = Instant::now();
                let (deadline, why) = match head_since {
                    Some(t) => (t + limits.header_timeout, Expired::Header),
                    None => (last + limits.idle_timeout, Expired::Idle),
                };
                if now >= deadline {
                    let m = front.metrics();
                    match why {
                        Expired::Idle => m.connections_idle_closed.fetch_add(1, Ordering::Relaxed),
                        Expired::Header => m.connections_header_timeouts.fetch_add(1, Ordering::Relaxed),
                    };
                    tracing::debug!(reason = ?why, "connection closed by timeout");
                    return WireEnd::Closed;
                }
                timer.as_mut().reset(tokio::time::Instant::from_std(deadline));
            }
            // Shutting down: nothing is in flight here (a partly received head is not).
            _ = stop.wait_for(|v| *v) => return WireEnd::Closed,
        }
    }
}

/// How a connection leaves the wire-level fast path (`wire`).
enum WireEnd {
    Closed,
    Hyper(BytesMut),
    /// Idle, with nothing read of a next request: to be served by this thread from now on.
    Move(usize),
}

/// Writes `head` then `body` (one `writev` when the socket takes both, as it nearly always
/// does for a tile); fails when the peer takes no byte for `limit`.
async fn write_two(stream: &TcpStream, head: &[u8], body: &[u8], limit: Duration) -> io::Result<()> {
    let (mut h, mut b) = (0, 0);
    while h < head.len() || b < body.len() {
        let bufs = [io::IoSlice::new(&head[h..]), io::IoSlice::new(&body[b..])];
        match stream.try_write_vectored(&bufs) {
            Ok(0) => return Err(io::ErrorKind::WriteZero.into()),
            Ok(mut n) => {
                let from_head = n.min(head.len() - h);
                h += from_head;
                n -= from_head;
                b += n;
            }
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                tokio::time::timeout(limit, stream.writable())
                    .await
                    .map_err(|_| io::ErrorKind::TimedOut)??;
            }
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// Counts a request as in flight on its connection until dropped (answered or abandoned).
struct Busy(Arc<Activity>);
impl Drop for Busy {
    fn drop(&mut self) {
        self.0.request_done();
    }
}

/// What a client past its connection cap gets before the connection is closed.
const TOO_MANY: &[u8] = b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/problem+json\r\ncache-control: no-store\r\nretry-after: 5\r\nconnection: close\r\ncontent-length: 165\r\n\r\n{\"type\":\"urn:terrastream:problem:too-many-connections\",\"title\":\"Service Unavailable\",\"status\":503,\"detail\":\"this client has too many connections open to the server\"}";

/// Accepts connections until `stop` turns true, serving each with `service` under `limits`
/// (counted in `shared` with the other serving threads'; with `Shared::balanced`, this is
/// thread `me` of them, taking handed-over connections from `inbox` too); then asks every
/// connection to close once its request in flight is answered, and returns when all are
/// closed (the caller bounds that wait).
pub async fn serve(
    listener: TcpListener,
    service: FastPath,
    limits: Limits,
    shared: &Arc<Shared>,
    me: usize,
    mut inbox: Option<Inbox>,
    mut stop: watch::Receiver<bool>,
) {
    let metrics = service.metrics().clone();
    // Every connection task holds a receiver; when all are dropped, every connection is closed.
    let (closed_tx, closed_rx) = watch::channel(());
    let mut builder = hyper::server::conn::http1::Builder::new();
    // Answer every request a client sent before shutting its write side (pipelining).
    builder.half_close(true).keep_alive(true);
    let for_conns = stop.clone();
    let spawn = |stream: TcpStream, addr: SocketAddr, slots: Slots| {
        let conn = Conn { stream, activity: Arc::new(Activity::new()), slots };
        let task = connection(
            conn,
            addr,
            service.clone(),
            builder.clone(),
            limits,
            for_conns.clone(),
            closed_rx.clone(),
        );
        tokio::spawn(task);
    };
    // A connection another thread accepted or served before.
    let start = |h: Handed| match TcpStream::from_std(h.stream) {
        Ok(stream) => spawn(stream, h.addr, h.slots),
        Err(e) => {
            tracing::warn!(client = %h.addr, error = %e, "cannot serve a connection handed over by another thread");
        }
    };
    // A handed-over connection; never, when this thread has no inbox.
    let handed = async |inbox: &mut Option<Inbox>| match inbox {
        Some(Inbox(rx)) => rx.recv().await,
        None => std::future::pending().await,
    };
    if shared.balance.is_some() {
        tokio::spawn(balance_loop(shared.clone(), me, stop.clone()));
    }
    'accept: loop {
        let permit = tokio::select! {
            Some(h) = handed(&mut inbox) => {
                start(h);
                continue;
            }
            p = shared.permits.clone().acquire_owned() => p,
            _ = stop.wait_for(|v| *v) => break,
        };
        let Ok(permit) = permit else { break };
        let accepted = loop {
            tokio::select! {
                Some(h) = handed(&mut inbox) => start(h),
                a = listener.accept() => break a,
                _ = stop.wait_for(|v| *v) => break 'accept,
            }
        };
        let (stream, addr) = match accepted {
            Ok(a) => a,
            Err(e) => {
                // Per-connection errors (reset before accept) are routine; running out of
                // descriptors is not: back off instead of spinning.
                let transient = matches!(
                    e.kind(),
                    io::ErrorKind::ConnectionAborted
                        | io::ErrorKind::ConnectionReset
                        | io::ErrorKind::ConnectionRefused
                );
                if !transient {
                    tracing::warn!(error = %e, "accept failed");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
                continue;
            }
        };
        let ip = addr.ip().to_canonical();
        let Some(client) = shared.clients.admit(ip, limits.per_client) else {
            metrics.connections_refused.fetch_add(1, Ordering::Relaxed);
            tracing::debug!(client = %ip, cap = limits.per_client, "connection refused: client at its connection cap");
            // Best effort, without waiting: a fresh socket's send buffer is empty.
            let _ = stream.try_write(TOO_MANY);
            drop(stream);
            continue;
        };
        // Tiles are small responses: send them without Nagle's delay.
        let _ = stream.set_nodelay(true);
        metrics.connections_open.fetch_add(1, Ordering::Relaxed);
        let to = shared.balance.as_ref().map_or(me, |b| {
            accept_target(me, b.threads.iter().map(|t| t.open.load(Ordering::Relaxed)), ACCEPT_SLACK)
        });
        let slots = Slots {
            _permit: permit,
            _client: client,
            open: OpenGauge(metrics.clone()),
            thread: ThreadGauge::new(shared, to),
        };
        if to == me {
            spawn(stream, addr, slots);
        } else {
            hand_over(stream, addr, slots, to);
        }
    }
    // Connections handed over and not yet started are closed here (nothing of them was read).
    drop(inbox);
    drop(listener);
    drop(closed_rx);
    closed_tx.closed().await;
}

/// Hands an idle connection (nothing of a next request read) to serving thread `to`; where
/// that fails (the thread has stopped: shutting down), the connection is closed.
fn hand_over(stream: TcpStream, addr: SocketAddr, mut slots: Slots, to: usize) {
    let Some(shared) = slots.thread.as_ref().map(|g| g.shared.clone()) else { return };
    let Some(b) = shared.balance.as_ref() else { return };
    let Some(sender) = b.senders.get(to) else { return };
    if slots.thread.as_ref().is_none_or(|g| g.thread != to) {
        let Some(gauge) = ThreadGauge::new(&shared, to) else { return };
        slots.thread = Some(gauge);
    }
    match stream.into_std() {
        Ok(stream) => {
            let metrics = slots.open.0.clone();
            if sender.send(Handed { stream, addr, slots }).is_err() {
                tracing::debug!(client = %addr, "connection closed: its new serving thread has stopped");
            } else {
                metrics.connections_moved.fetch_add(1, Ordering::Relaxed);
            }
        }
        Err(e) => tracing::warn!(client = %addr, error = %e, "cannot hand a connection to another thread"),
    }
}

/// Serves one accepted connection: the wire-level fast path, then hyper for the rest of its
/// life; drops `closed_rx` when the connection is closed.
async fn connection(
    mut conn: Conn,
    addr: SocketAddr,
    service: FastPath,
    builder: hyper::server::conn::http1::Builder,
    limits: Limits,
    mut stop: watch::Receiver<bool>,
    closed_rx: watch::Receiver<()>,
) {
    let metrics = service.metrics().clone();
    let activity = conn.activity.clone();
    let pre = if service.wire_enabled() {
        match wire(&mut conn.stream, &service, limits, conn.slots.thread.as_ref(), &mut stop).await {
            WireEnd::Hyper(rest) => rest.freeze(),
            WireEnd::Closed => return,
            WireEnd::Move(to) => {
                let Conn { stream, slots, .. } = conn;
                hand_over(stream, addr, slots, to);
                return;
            }
        }
    } else {
        Bytes::new()
    };
    if !pre.is_empty() {
        // The head hyper reads next started arriving already.
        activity.read();
    }
    // hyper's requests count in the thread's load too (`balance_loop`), though only the fast
    // path's connections can move.
    let load = conn.slots.thread.as_ref().map(|g| (g.shared.clone(), g.thread));
    let svc = {
        let activity = activity.clone();
        hyper::service::service_fn(move |req: hyper::Request<hyper::body::Incoming>| {
            activity.request_started();
            if let Some((s, t)) = &load {
                s.count_answered(*t);
            }
            let busy = Busy(activity.clone());
            let mut req = req.map(axum::body::Body::new);
            req.extensions_mut().insert(ConnectInfo(Peer(addr)));
            let fut = service.clone().call(req);
            async move {
                let r = fut.await;
                drop(busy);
                r
            }
        })
    };
    let conn = builder.serve_connection(TokioIo::new(Rewind { pre, conn }), svc);
    let mut conn = std::pin::pin!(conn);
    let expired = activity.expired(limits);
    let mut expired = std::pin::pin!(expired);
    let mut stopping = false;
    loop {
        tokio::select! {
            r = conn.as_mut() => {
                if let Err(e) = r {
                    tracing::trace!(error = %e, "connection ended with an error");
                }
                break;
            }
            why = expired.as_mut() => {
                match why {
                    Expired::Idle => metrics.connections_idle_closed.fetch_add(1, Ordering::Relaxed),
                    Expired::Header => metrics.connections_header_timeouts.fetch_add(1, Ordering::Relaxed),
                };
                tracing::debug!(client = %addr, reason = ?why, "connection closed by timeout");
                // Nothing is in flight: dropping the connection closes the socket.
                break;
            }
            _ = stop.wait_for(|v| *v), if !stopping => {
                stopping = true;
                conn.as_mut().graceful_shutdown();
            }
        }
    }
    drop(closed_rx);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_thread_sheds_only_when_busier_by_half_and_holding_more() {
        // All connections on thread 0, thread 1 idle: half of them move to 1.
        assert_eq!(shed_plan(0, &[5000, 0], &[50, 0], 500), Some((25, 1)));
        // The idle thread itself sheds nothing.
        assert_eq!(shed_plan(1, &[5000, 0], &[50, 0], 500), None);
        // Evenly loaded, or too little traffic to matter, or no connection to spare: nothing.
        assert_eq!(shed_plan(0, &[5000, 4000], &[25, 25], 500), None);
        assert_eq!(shed_plan(0, &[400, 0], &[50, 0], 500), None);
        assert_eq!(shed_plan(0, &[5000, 0], &[1, 0], 500), None);
        assert_eq!(shed_plan(0, &[5000, 100], &[26, 25], 500), None);
        // Busier by more than twice but with fewer connections (heavier ones): nothing.
        assert_eq!(shed_plan(0, &[5000, 100], &[10, 30], 500), None);
        // Toward the least busy of several (the first of equals); never toward itself.
        assert_eq!(shed_plan(2, &[100, 50, 6000, 50], &[10, 10, 30, 4], 500), Some((10, 1)));
        assert_eq!(shed_plan(0, &[6000], &[30], 500), None);
        assert_eq!(shed_plan(3, &[6000, 0], &[30, 0], 500), None);
    }

    #[test]
    fn a_thread_passes_new_connections_on_only_past_twice_the_least_plus_slack() {
        assert_eq!(accept_target(0, [63, 0], 64), 0);
        assert_eq!(accept_target(0, [64, 0], 64), 1);
        assert_eq!(accept_target(0, [100, 20], 64), 0);
        assert_eq!(accept_target(0, [104, 20], 64), 1);
        assert_eq!(accept_target(1, [0, 500, 0], 64), 0);
        assert_eq!(accept_target(0, [500], 64), 0);
        assert_eq!(accept_target(2, [5, 5], 64), 2);
        // One queue's worth of connections, accepted one at a time by thread 0: about 2:1.
        let mut open = [0usize, 0];
        for _ in 0..3000 {
            open[accept_target(0, open, 64)] += 1;
        }
        assert!(open[0] <= 2 * open[1] + 64 && open[1] > 900, "{open:?}");
    }

    #[test]
    fn per_client_cap_counts_and_releases() {
        let c = Arc::new(Clients::default());
        let a: IpAddr = "127.0.0.1".parse().unwrap();
        let b: IpAddr = "127.0.0.2".parse().unwrap();
        let s1 = c.admit(a, 2).unwrap();
        let _s2 = c.admit(a, 2).unwrap();
        assert!(c.admit(a, 2).is_none());
        let _sb = c.admit(b, 2).unwrap();
        drop(s1);
        let _s3 = c.admit(a, 2).unwrap();
        assert!((0..1000).all(|_| c.admit(a, 0).is_some_and(|s| {
            drop(s);
            true
        })));
        assert_eq!(TOO_MANY.len() - TOO_MANY.windows(4).position(|w| w == b"\r\n\r\n").unwrap() - 4, 165);
    }
}
