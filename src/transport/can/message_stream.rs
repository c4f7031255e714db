//! A byte stream for [`serve_stream`](super::serve_stream) that keeps message boundaries: what it
//! reads are the received ISO-TP messages back to back, and every `poll_write` becomes one
//! outgoing message. `serve_stream` writes each reply packet with one `write_all`, and
//! `poll_write` here always takes the whole buffer, so one reply is one message.

use std::pin::Pin;
use std::task::{Context, Poll};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::sync::mpsc;

/// The bus's end: an `AsyncRead + AsyncWrite`.
pub(super) struct MessageStream {
    from_link: mpsc::Receiver<Vec<u8>>,
    to_link: mpsc::UnboundedSender<Vec<u8>>,
    current: Vec<u8>,
    read_at: usize,
}

/// The link's end.
pub(super) struct LinkEnds {
    /// Received messages for the bus (bounded: a flood is dropped, not buffered without end).
    pub to_bus: mpsc::Sender<Vec<u8>>,
    /// Reply packets from the bus, one per message. Unbounded: the bus writes only replies to
    /// requests it was given, so this is bounded by the inbound side.
    pub from_bus: mpsc::UnboundedReceiver<Vec<u8>>,
}

pub(super) fn pair(inbound_capacity: usize) -> (MessageStream, LinkEnds) {
    let (to_bus, from_link) = mpsc::channel(inbound_capacity);
    let (to_link, from_bus) = mpsc::unbounded_channel();
    (MessageStream { from_link, to_link, current: Vec::new(), read_at: 0 }, LinkEnds { to_bus, from_bus })
}

impl AsyncRead for MessageStream {
    fn poll_read(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<std::io::Result<()>> {
        let this = &mut *self;
        while this.read_at == this.current.len() {
            match this.from_link.poll_recv(cx) {
                Poll::Ready(Some(message)) => {
                    this.current = message;
                    this.read_at = 0;
                }
                // The link has ended: end of file.
                Poll::Ready(None) => return Poll::Ready(Ok(())),
                Poll::Pending => return Poll::Pending,
            }
        }
        let n = buf.remaining().min(this.current.len() - this.read_at);
        buf.put_slice(&this.current[this.read_at..this.read_at + n]);
        this.read_at += n;
        Poll::Ready(Ok(()))
    }
}

impl AsyncWrite for MessageStream {
    fn poll_write(self: Pin<&mut Self>, _cx: &mut Context<'_>, buf: &[u8]) -> Poll<std::io::Result<usize>> {
        if buf.is_empty() {
            return Poll::Ready(Ok(0));
        }
        match self.to_link.send(buf.to_vec()) {
            Ok(()) => Poll::Ready(Ok(buf.len())),
            Err(_) => Poll::Ready(Err(std::io::ErrorKind::BrokenPipe.into())),
        }
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    #[tokio::test]
    async fn reads_messages_back_to_back_and_each_write_is_one_message() {
        let (mut stream, mut ends) = pair(4);
        ends.to_bus.send(vec![1, 2, 3]).await.unwrap();
        ends.to_bus.send(vec![4]).await.unwrap();
        let mut buf = [0u8; 2];
        let mut read = Vec::new();
        while read.len() < 4 {
            let n = stream.read(&mut buf).await.unwrap();
            read.extend_from_slice(&buf[..n]);
        }
        assert_eq!(read, [1, 2, 3, 4]);

        stream.write_all(&[9; 100]).await.unwrap();
        stream.write_all(&[8; 3]).await.unwrap();
        assert_eq!(ends.from_bus.recv().await.unwrap(), vec![9; 100]);
        assert_eq!(ends.from_bus.recv().await.unwrap(), vec![8; 3]);

        drop(ends);
        assert_eq!(stream.read(&mut buf).await.unwrap(), 0, "end of file once the link is gone");
        assert!(stream.write_all(&[1]).await.is_err());
    }
}
