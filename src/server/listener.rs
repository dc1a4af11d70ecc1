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

use std::collections::HashMap;
use std::convert::Infallible;
use std::io;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use axum::extract::{ConnectInfo, Request};
use hyper_util::rt::TokioIo;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore, watch};
use tower::Service;

use super::metrics::Metrics;

/// The peer address of a connection, as `ConnectInfo` in every request's extensions.
#[derive(Clone, Copy, Debug)]
pub struct Peer(pub SocketAddr);

/// The connection limits (from `Config`).
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    pub max_connections: usize,
    /// 0 = no per-client limit.
    pub per_client: usize,
    pub header_timeout: Duration,
    pub idle_timeout: Duration,
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
    _permit: OwnedSemaphorePermit,
    _client: ClientSlot,
    _open: OpenGauge,
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

/// Counts a request as in flight on its connection until dropped (answered or abandoned).
struct Busy(Arc<Activity>);
impl Drop for Busy {
    fn drop(&mut self) {
        self.0.request_done();
    }
}

/// What a client past its connection cap gets before the connection is closed.
const TOO_MANY: &[u8] = b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/problem+json\r\ncache-control: no-store\r\nretry-after: 5\r\nconnection: close\r\ncontent-length: 165\r\n\r\n{\"type\":\"urn:terrastream:problem:too-many-connections\",\"title\":\"Service Unavailable\",\"status\":503,\"detail\":\"this client has too many connections open to the server\"}";

/// Accepts connections until `stop` turns true, serving each with `service` under `limits`;
/// then asks every connection to close once its request in flight is answered, and returns
/// when all are closed (the caller bounds that wait).
pub async fn serve<S>(
    listener: TcpListener,
    service: S,
    limits: Limits,
    metrics: Arc<Metrics>,
    mut stop: watch::Receiver<bool>,
) where
    S: Service<Request, Response = axum::response::Response, Error = Infallible> + Clone + Send + 'static,
    S::Future: Send + 'static,
{
    let permits = Arc::new(Semaphore::new(limits.max_connections));
    let clients = Arc::new(Clients::default());
    // Every connection task holds a receiver; when all are dropped, every connection is closed.
    let (closed_tx, closed_rx) = watch::channel(());
    let mut builder = hyper::server::conn::http1::Builder::new();
    // Answer every request a client sent before shutting its write side (pipelining).
    builder.half_close(true).keep_alive(true);
    loop {
        let permit = tokio::select! {
            p = permits.clone().acquire_owned() => p,
            _ = stop.wait_for(|v| *v) => break,
        };
        let Ok(permit) = permit else { break };
        let accepted = tokio::select! {
            a = listener.accept() => a,
            _ = stop.wait_for(|v| *v) => break,
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
        let Some(client) = clients.admit(ip, limits.per_client) else {
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
        let activity = Arc::new(Activity::new());
        let conn = Conn {
            stream,
            activity: activity.clone(),
            _permit: permit,
            _client: client,
            _open: OpenGauge(metrics.clone()),
        };
        let svc = {
            let (service, activity) = (service.clone(), activity.clone());
            hyper::service::service_fn(move |req: hyper::Request<hyper::body::Incoming>| {
                activity.request_started();
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
        let builder = builder.clone();
        let (mut stop, closed_rx, metrics) = (stop.clone(), closed_rx.clone(), metrics.clone());
        tokio::spawn(async move {
            let conn = builder.serve_connection(TokioIo::new(conn), svc);
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
        });
    }
    drop(listener);
    drop(closed_rx);
    closed_tx.closed().await;
}

#[cfg(test)]
mod tests {
    use super::*;

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
