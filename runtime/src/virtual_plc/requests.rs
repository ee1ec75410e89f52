//! Modbus TCP requests checked before they reach the server's decoder.
//!
//! tokio-modbus trusts a request's counts: a Write Multiple Coils (function
//! 15) whose byte count is too small for its quantity indexes past the frame
//! and panics, ending the client's connection with a backtrace. [`Checked`]
//! passes a client's bytes to the server one whole frame at a time, and ends
//! the connection with the error "malformed request: …" (one line in the
//! virtual PLC's log) at the first frame whose lengths do not add up.

use std::io;
use std::pin::Pin;
use std::task::{Context, Poll, ready};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// MBAP header: transaction, protocol, length (2 bytes each), then the unit.
const HEADER: usize = 6;

/// A client's stream whose requests are checked frame by frame.
pub(super) struct Checked<S> {
    inner: S,
    /// Bytes read from the client, not yet handed to the server.
    pending: Vec<u8>,
    /// How many bytes at the front of `pending` are whole, checked frames.
    checked: usize,
}

impl<S> Checked<S> {
    pub(super) fn new(inner: S) -> Self {
        Checked {
            inner,
            pending: Vec::new(),
            checked: 0,
        }
    }
}

/// The length of the frame at the front of `bytes`, once its header is in.
fn frame_length(bytes: &[u8]) -> Option<usize> {
    let length = u16::from_be_bytes([*bytes.get(4)?, *bytes.get(5)?]);
    Some(HEADER + usize::from(length))
}

/// Whether a whole frame's lengths add up; why not, if they do not.
fn check(frame: &[u8]) -> Result<(), String> {
    let length = frame.len() - HEADER;
    if !(2..=254).contains(&length) {
        return Err(format!(
            "a frame of {length} bytes after its header (2 to 254)"
        ));
    }
    let pdu = &frame[HEADER + 1..];
    // Where the byte count is, and how many values it counts: the requests
    // whose counts tokio-modbus trusts.
    let (function, count_at, quantity_at, per_value) = match pdu[0] {
        0x0F => (0x0F, 5, 3, Bits),
        0x10 => (0x10, 5, 3, Words),
        // Read/Write Multiple Registers: the write quantity is the second.
        0x17 => (0x17, 9, 7, Words),
        _ => return Ok(()),
    };
    let (Some(quantity), Some(&count)) = (pdu.get(quantity_at..quantity_at + 2), pdu.get(count_at))
    else {
        return Err(format!(
            "function {function} without its quantity and byte count"
        ));
    };
    let quantity = usize::from(u16::from_be_bytes([quantity[0], quantity[1]]));
    let needed = match per_value {
        Bits => quantity.div_ceil(8),
        Words => 2 * quantity,
    };
    let count = usize::from(count);
    if count != needed || pdu.len() != count_at + 1 + count {
        return Err(format!(
            "function {function} for {quantity} values with a byte count of {count} and {} bytes of data",
            pdu.len().saturating_sub(count_at + 1)
        ));
    }
    Ok(())
}

/// What a request's values are written as.
enum Width {
    Bits,
    Words,
}
use Width::{Bits, Words};

impl<S: AsyncRead + Unpin> AsyncRead for Checked<S> {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        out: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        loop {
            if this.checked > 0 {
                let n = this.checked.min(out.remaining());
                out.put_slice(&this.pending[..n]);
                this.pending.drain(..n);
                this.checked -= n;
                return Poll::Ready(Ok(()));
            }
            if let Some(length) = frame_length(&this.pending)
                && this.pending.len() >= length
            {
                check(&this.pending[..length]).map_err(|why| {
                    io::Error::new(
                        io::ErrorKind::InvalidData,
                        format!("malformed request: {why}"),
                    )
                })?;
                this.checked = length;
                continue;
            }
            let mut chunk = [0u8; 512];
            let mut read = ReadBuf::new(&mut chunk);
            ready!(Pin::new(&mut this.inner).poll_read(cx, &mut read))?;
            if read.filled().is_empty() {
                // The client is gone; a partial frame goes with it.
                return Poll::Ready(Ok(()));
            }
            this.pending.extend_from_slice(read.filled());
        }
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Checked<S> {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bytes: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.get_mut().inner).poll_write(cx, bytes)
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::check;

    /// A request of `head`'s function: `head` (unit, function, fields), then
    /// a write `quantity`, a byte `count` and `data`, in an MBAP frame.
    fn request(head: &[u8], quantity: u16, count: u8, data: &[u8]) -> Vec<u8> {
        let mut pdu = head.to_vec();
        pdu.extend(quantity.to_be_bytes());
        pdu.push(count);
        pdu.extend(data);
        let mut frame = vec![0, 1, 0, 0];
        frame.extend(u16::try_from(pdu.len()).expect("short").to_be_bytes());
        frame.extend(pdu);
        frame
    }

    /// A Write Multiple Coils request for `quantity` coils with `data`.
    fn fc15(quantity: u16, count: u8, data: &[u8]) -> Vec<u8> {
        request(&[1, 0x0F, 0, 0], quantity, count, data)
    }

    #[test]
    fn a_write_of_coils_needs_a_byte_per_eight_coils() {
        assert_eq!(check(&fc15(10, 2, &[0xFF, 0x03])), Ok(()));
        assert!(check(&fc15(100, 2, &[0xFF, 0x03])).is_err());
        assert!(check(&fc15(10, 2, &[0xFF])).is_err());
        // Reads are passed as they are.
        let read = [0, 1, 0, 0, 0, 6, 1, 0x01, 0, 0, 0, 8];
        assert_eq!(check(&read), Ok(()));
    }

    /// Found by the `modbus_requests` fuzz target: a Read/Write Multiple
    /// Registers whose write quantity doubles past 16 bits made tokio-modbus
    /// overflow (a panic where overflow is checked).
    #[test]
    fn a_read_write_of_registers_needs_two_bytes_per_register() {
        let frame = |quantity, count, data: &[u8]| {
            request(&[1, 0x17, 0, 0, 0, 1, 0, 0], quantity, count, data)
        };
        assert_eq!(check(&frame(2, 4, &[0, 1, 0, 2])), Ok(()));
        assert!(check(&frame(0x8000, 0, &[])).is_err());
        assert!(check(&frame(2, 4, &[0, 1])).is_err());
    }
}
