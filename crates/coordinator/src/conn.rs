//! Accepted connections, bounded in number and closed when silent.
//!
//! Without this, every TCP connection anyone opens is kept for as long as they like: a few
//! hundred idle ones are enough to leave the coordinator slow to answer real clients. Here at
//! most `max` connections are open at once (the next waits in the kernel's backlog until one
//! closes), and a connection that has sent nothing for a while (`Config::idle_connection`) is
//! closed. HTTP/2
//! keepalive pings, which live clients answer, count as traffic, so only dead or deliberately
//! silent peers are cut off.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};
use tokio_stream::wrappers::ReceiverStream;
use tonic::transport::server::{Connected, TcpConnectInfo};

/// The stream of accepted connections handed to tonic.
pub(crate) struct Limited;

impl Limited {
    /// Accepts on `listener` in a task of its own, holding at most `max` connections open.
    /// The task (and with it the listening socket) ends when the server drops the stream.
    #[allow(clippy::new_ret_no_self)]
    pub(crate) fn new(
        listener: TcpListener,
        max: usize,
        idle: Duration,
    ) -> ReceiverStream<io::Result<Conn>> {
        let (tx, rx) = mpsc::channel(1);
        let slots = Arc::new(Semaphore::new(max.max(1)));
        tokio::spawn(async move {
            loop {
                let permit = tokio::select! {
                    p = slots.clone().acquire_owned() => match p {
                        Ok(p) => p,
                        Err(_) => return,
                    },
                    _ = tx.closed() => return,
                };
                let accepted = tokio::select! {
                    a = listener.accept() => a,
                    _ = tx.closed() => return,
                };
                match accepted {
                    Ok((stream, _)) => {
                        let _ = stream.set_nodelay(true);
                        let conn = Conn {
                            stream,
                            _permit: permit,
                            idle_after: idle,
                            idle: Box::pin(tokio::time::sleep(idle)),
                        };
                        if tx.send(Ok(conn)).await.is_err() {
                            return;
                        }
                    }
                    Err(e) => {
                        // Out of file descriptors, or a connection reset before it was
                        // accepted: not the server's end. Wait a moment rather than spin.
                        tracing::warn!("accepting a connection: {e}");
                        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
                    }
                }
            }
        });
        ReceiverStream::new(rx)
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
}

impl AsyncRead for Conn {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
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
