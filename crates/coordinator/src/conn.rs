//! Accepted connections: bounded in number, closed when silent, and closed when they do not
//! prove themselves in time.
//!
//! Without this, every TCP connection anyone opens is kept for as long as they like: a few
//! hundred idle ones are enough to leave the coordinator slow to answer real clients. Here at
//! most `max` connections are open at once, and a connection that has sent nothing for a
//! while (`Config::idle_connection`) is closed. HTTP/2 keepalive pings, which live clients
//! answer, count as traffic, so only dead or deliberately silent peers are cut off by that.
//!
//! Traffic is not trust, though: a peer without the token can ping, or send a login body a
//! byte at a time, for ever. So a connection is **unproven** until a request on it passes the
//! auth check ([`Gate::prove`], called by the gRPC interceptor and the dashboard's check; with
//! no token configured, any request passes). The [`Gate`]'s invariant: unproven connections
//! never hold more than half the slots, nor more than a quarter of that share from one IP
//! address, and none stays unproven past [`Gate`]'s deadline. A new connection that would pass
//! a cap closes the *oldest* unproven one in its way, and a new connection that finds every
//! slot taken closes the oldest unproven one if there is one. Honest clients send their first
//! request within milliseconds of connecting, so they are the newest unproven connections, not
//! the oldest, and a client with the token always gets a slot however many connections a peer
//! without it opens. With no token configured there is nothing to prove: every connection is
//! proven from the start. What a peer with the token can do is a different threat (one the
//! per-worker lease and connection limits bound).

use std::collections::{BTreeMap, HashMap};
use std::future::Future;
use std::io;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::futures::OwnedNotified;
use tokio::sync::{mpsc, Notify, OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};
use tokio_stream::wrappers::ReceiverStream;
use tonic::transport::server::{Connected, TcpConnectInfo};

/// How long a new connection has to make a request that passes the auth check.
pub(crate) const PROVE_WITHIN: Duration = Duration::from_secs(10);

/// The stream of accepted connections handed to the server, and the gate they pass.
pub(crate) struct Limited;

impl Limited {
    /// Accepts on `listener` in a task of its own, holding at most `max` connections open.
    /// The task (and with it the listening socket) ends when the server drops the stream.
    #[allow(clippy::new_ret_no_self)]
    /// With `open` (no token configured, so there is nothing to prove) every connection is
    /// proven from the start, and only the limit on their number and the idle timeout apply.
    pub(crate) fn new(
        listener: TcpListener,
        max: usize,
        idle: Duration,
        open: bool,
    ) -> (ReceiverStream<io::Result<Conn>>, Arc<Gate>) {
        Self::with_deadline(listener, max, idle, (!open).then_some(PROVE_WITHIN))
    }

    /// [`Limited::new`] with another deadline for proving a connection (tests); `None` for
    /// none to prove.
    pub(crate) fn with_deadline(
        listener: TcpListener,
        max: usize,
        idle: Duration,
        prove_within: Option<Duration>,
    ) -> (ReceiverStream<io::Result<Conn>>, Arc<Gate>) {
        let (tx, rx) = mpsc::channel(1);
        let max = max.max(1);
        let slots = Arc::new(Semaphore::new(max));
        let gate = Arc::new(Gate::new(max, prove_within));
        let g = gate.clone();
        tokio::spawn(async move {
            loop {
                let accepted = tokio::select! {
                    a = listener.accept() => a,
                    _ = tx.closed() => return,
                };
                let (stream, peer) = match accepted {
                    Ok(a) => a,
                    Err(e) => {
                        // Out of file descriptors, or a connection reset before it was
                        // accepted: not the server's end. Wait a moment rather than spin.
                        tracing::warn!("accepting a connection: {e}");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                };
                let permit = match slots.clone().try_acquire_owned() {
                    Ok(p) => p,
                    Err(_) => {
                        // Full: an unproven connection makes way, else wait for one to close.
                        g.evict_oldest(None);
                        tokio::select! {
                            p = slots.clone().acquire_owned() => match p {
                                Ok(p) => p,
                                Err(_) => return,
                            },
                            _ = tx.closed() => return,
                        }
                    }
                };
                let _ = stream.set_nodelay(true);
                let conn = g.admit(stream, peer, permit, idle);
                if tx.send(Ok(conn)).await.is_err() {
                    return;
                }
            }
        });
        (ReceiverStream::new(rx), gate)
    }
}

/// Which connections have proven themselves (see the module doc).
pub(crate) struct Gate {
    state: Mutex<GateState>,
    /// Most unproven connections at once.
    max_unproven: usize,
    /// Most unproven connections from one IP address at once.
    max_unproven_per_ip: usize,
    /// How long a connection has to prove itself; `None` when every connection is proven
    /// from the start (no token configured).
    prove_within: Option<Duration>,
}

#[derive(Default)]
struct GateState {
    /// Admission order, so the oldest unproven connection is the first entry.
    next: u64,
    unproven: BTreeMap<u64, Unproven>,
    /// Every open connection by its peer's address (unique among open connections): how the
    /// gRPC interceptor, which sees the address, finds the connection.
    by_peer: HashMap<SocketAddr, Arc<Trust>>,
}

struct Unproven {
    peer: SocketAddr,
    trust: Arc<Trust>,
}

/// One connection's standing, shared by the connection and the gate.
pub(crate) struct Trust {
    seq: u64,
    peer: SocketAddr,
    gate: std::sync::Weak<Gate>,
    proven: std::sync::atomic::AtomicBool,
    /// Notified when the gate closes the connection.
    evict: Arc<Notify>,
}

impl Trust {
    /// The address the connection comes from.
    pub(crate) fn peer(&self) -> IpAddr {
        self.peer.ip()
    }

    /// Marks the connection proven: a request on it passed the auth check.
    pub(crate) fn prove(&self) {
        if self.proven.swap(true, std::sync::atomic::Ordering::AcqRel) {
            return;
        }
        if let Some(g) = self.gate.upgrade() {
            g.lock().unproven.remove(&self.seq);
        }
    }

    fn is_proven(&self) -> bool {
        self.proven.load(std::sync::atomic::Ordering::Acquire)
    }
}

impl Gate {
    fn new(max: usize, prove_within: Option<Duration>) -> Self {
        let max_unproven = (max / 2).max(1);
        Self {
            state: Mutex::default(),
            max_unproven,
            // Half the share: a burst of honest connections from behind one NAT rarely comes
            // near it, and one address still cannot take the whole share.
            max_unproven_per_ip: (max_unproven / 2).max(1),
            prove_within,
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, GateState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Marks the connection from `peer` proven (the gRPC interceptor's way in).
    pub(crate) fn prove(&self, peer: Option<SocketAddr>) {
        let trust = peer.and_then(|p| self.lock().by_peer.get(&p).cloned());
        if let Some(t) = trust {
            t.prove();
        }
    }

    /// How many open connections have not proven themselves.
    #[cfg(test)]
    pub(crate) fn unproven(&self) -> usize {
        self.lock().unproven.len()
    }

    fn admit(
        self: &Arc<Self>,
        stream: TcpStream,
        peer: SocketAddr,
        permit: OwnedSemaphorePermit,
        idle: Duration,
    ) -> Conn {
        let evict = Arc::new(Notify::new());
        let mut st = self.lock();
        let seq = st.next;
        st.next += 1;
        let trust = Arc::new(Trust {
            seq,
            peer,
            gate: Arc::downgrade(self),
            proven: self.prove_within.is_none().into(),
            evict: evict.clone(),
        });
        let conn = |trust: Arc<Trust>| Conn {
            stream,
            _permit: permit,
            idle_after: idle,
            idle: Box::pin(tokio::time::sleep(idle)),
            deadline: Box::pin(tokio::time::sleep(self.prove_within.unwrap_or(idle))),
            evicted: Box::pin(evict.notified_owned()),
            trust,
        };
        if trust.is_proven() {
            st.by_peer.insert(peer, trust.clone());
            return conn(trust);
        }
        let same_ip = st
            .unproven
            .values()
            .filter(|u| u.peer.ip() == peer.ip())
            .count();
        if same_ip >= self.max_unproven_per_ip {
            Self::evict_in(&mut st, Some(peer.ip()));
        }
        if st.unproven.len() >= self.max_unproven {
            Self::evict_in(&mut st, None);
        }
        st.unproven.insert(
            seq,
            Unproven {
                peer,
                trust: trust.clone(),
            },
        );
        st.by_peer.insert(peer, trust.clone());
        drop(st);
        conn(trust)
    }

    /// Closes the oldest unproven connection (from `ip`, if given); false if there is none.
    pub(crate) fn evict_oldest(&self, ip: Option<IpAddr>) -> bool {
        Self::evict_in(&mut self.lock(), ip)
    }

    fn evict_in(st: &mut GateState, ip: Option<IpAddr>) -> bool {
        let oldest = st
            .unproven
            .iter()
            .find(|(_, u)| ip.is_none_or(|ip| u.peer.ip() == ip))
            .map(|(&seq, _)| seq);
        match oldest.and_then(|seq| st.unproven.remove(&seq)) {
            Some(u) => {
                tracing::debug!("closing unproven connection from {} to make room", u.peer);
                u.trust.evict.notify_one();
                true
            }
            None => false,
        }
    }

    fn forget(&self, trust: &Trust) {
        let mut st = self.lock();
        st.unproven.remove(&trust.seq);
        if st
            .by_peer
            .get(&trust.peer)
            .is_some_and(|t| t.seq == trust.seq)
        {
            st.by_peer.remove(&trust.peer);
        }
    }
}

/// An accepted connection: its slot is freed when it closes.
pub(crate) struct Conn {
    stream: TcpStream,
    _permit: OwnedSemaphorePermit,
    /// How long the peer may stay silent.
    idle_after: Duration,
    /// Fires when the peer has sent nothing for `idle_after`.
    idle: Pin<Box<Sleep>>,
    /// Fires when the connection has had its time to prove itself.
    deadline: Pin<Box<Sleep>>,
    /// Fires when the gate closes the connection to make room.
    evicted: Pin<Box<OwnedNotified>>,
    trust: Arc<Trust>,
}

impl Conn {
    /// The connection's standing, for the dashboard to mark it proven.
    pub(crate) fn trust(&self) -> Arc<Trust> {
        self.trust.clone()
    }

    /// Why the gate closes the connection now, if it does.
    fn closing(&mut self, cx: &mut Context<'_>) -> Option<&'static str> {
        if self.evicted.as_mut().poll(cx).is_ready() {
            return Some("closed to make room: it had not authenticated");
        }
        if !self.trust.is_proven() && self.deadline.as_mut().poll(cx).is_ready() {
            return Some("no authenticated request in time");
        }
        None
    }
}

impl Drop for Conn {
    fn drop(&mut self) {
        if let Some(g) = self.trust.gate.upgrade() {
            g.forget(&self.trust);
        }
    }
}

impl AsyncRead for Conn {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        if let Some(why) = self.closing(cx) {
            return Poll::Ready(Err(io::Error::new(io::ErrorKind::PermissionDenied, why)));
        }
        let before = buf.filled().len();
        match Pin::new(&mut self.stream).poll_read(cx, buf) {
            Poll::Ready(r) => {
                if buf.filled().len() > before {
                    let next = Instant::now() + self.idle_after;
                    self.idle.as_mut().reset(next);
                }
                Poll::Ready(r)
            }
            Poll::Pending => match self.idle.as_mut().poll(cx) {
                Poll::Ready(()) => Poll::Ready(Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    "connection idle for too long",
                ))),
                Poll::Pending => Poll::Pending,
            },
        }
    }
}

impl AsyncWrite for Conn {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

impl Connected for Conn {
    type ConnectInfo = TcpConnectInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        self.stream.connect_info()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio_stream::StreamExt;

    /// Serves `Limited` connections that echo what they read and prove themselves on `!`.
    async fn echo_server(max: usize, prove_within: Option<Duration>) -> (SocketAddr, Arc<Gate>) {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("addr");
        let (mut incoming, gate) =
            Limited::with_deadline(listener, max, Duration::from_secs(60), prove_within);
        tokio::spawn(async move {
            while let Some(Ok(mut c)) = incoming.next().await {
                tokio::spawn(async move {
                    let mut buf = [0u8; 64];
                    while let Ok(n @ 1..) = c.read(&mut buf).await {
                        if buf[..n].contains(&b'!') {
                            c.trust().prove();
                        }
                        if c.write_all(&buf[..n]).await.is_err() {
                            return;
                        }
                    }
                });
            }
        });
        (addr, gate)
    }

    /// Whether the server has closed `s` (within a second).
    async fn closed(s: &mut TcpStream) -> bool {
        let mut buf = [0u8; 64];
        tokio::time::timeout(Duration::from_secs(1), async {
            loop {
                match s.read(&mut buf).await {
                    Ok(0) | Err(_) => return true,
                    Ok(_) => {}
                }
            }
        })
        .await
        .unwrap_or(false)
    }

    async fn echoes(s: &mut TcpStream, what: &[u8]) -> bool {
        let mut buf = vec![0u8; what.len()];
        s.write_all(what).await.is_ok()
            && tokio::time::timeout(Duration::from_secs(2), s.read_exact(&mut buf))
                .await
                .is_ok_and(|r| r.is_ok())
            && buf == what
    }

    #[tokio::test]
    async fn a_connection_that_never_proves_itself_is_closed_at_the_deadline() {
        let (addr, _gate) = echo_server(64, Some(Duration::from_millis(300))).await;
        let mut chatty = TcpStream::connect(addr).await.expect("connect");
        let mut proven = TcpStream::connect(addr).await.expect("connect");
        assert!(echoes(&mut proven, b"!").await);
        // Traffic alone does not keep a connection: it is closed at the deadline.
        assert!(echoes(&mut chatty, b"a").await);
        tokio::time::sleep(Duration::from_millis(400)).await;
        let _ = chatty.write_all(b"b").await;
        assert!(
            closed(&mut chatty).await,
            "an unproven connection outlived its deadline"
        );
        assert!(echoes(&mut proven, b"still here").await);
    }

    #[tokio::test]
    async fn unproven_connections_keep_to_their_share_and_make_way() {
        let max = 16;
        let (addr, gate) = echo_server(max, Some(Duration::from_secs(60))).await;
        // Far more unproven connections than there are slots.
        let mut crowd = Vec::new();
        for _ in 0..4 * max {
            crowd.push(TcpStream::connect(addr).await.expect("connect"));
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
        assert!(gate.unproven() <= max / 2, "{} unproven", gate.unproven());
        // A newcomer always gets in and, once proven, stays, however many more arrive.
        let mut honest = TcpStream::connect(addr).await.expect("connect");
        assert!(
            echoes(&mut honest, b"!").await,
            "the newcomer was not served"
        );
        for _ in 0..4 * max {
            crowd.push(TcpStream::connect(addr).await.expect("connect"));
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
        assert!(
            echoes(&mut honest, b"proven").await,
            "a proven connection was closed"
        );
        assert!(gate.unproven() <= max / 2, "{} unproven", gate.unproven());
        // Most of the crowd was closed to make room.
        let mut open = 0;
        for s in &mut crowd {
            if !closed(s).await {
                open += 1;
            }
        }
        assert!(open <= max, "{open} of the crowd still open");
    }
}
