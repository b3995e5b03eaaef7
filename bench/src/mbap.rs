//! A minimal Modbus TCP client for load generation: fixed requests written as bytes, fixed-size
//! answers read whole, so that the client costs as little CPU as possible and the same for every
//! server it measures.

use std::io;
use std::net::SocketAddr;

use rustls_pki_types::ServerName;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_rustls::client::TlsStream;
use tokio_rustls::TlsConnector;
use tokio_util::either::Either;

/// MBAP header (7 bytes) + function, byte count and 125 registers.
const FC03_125_ANSWER: usize = 7 + 2 + 250;
/// MBAP header + FC 06 echo (function, address, value).
const FC06_ANSWER: usize = 7 + 5;

/// One client connection, plain or over TLS (Modbus/TCP Security).
pub(crate) struct Client {
    stream: Either<TcpStream, TlsStream<TcpStream>>,
    transaction: u16,
    answer: Vec<u8>,
}

// === impl Client ===

impl Client {
    pub(crate) async fn connect(addr: SocketAddr) -> io::Result<Self> {
        let stream = TcpStream::connect(addr).await?;
        stream.set_nodelay(true)?;
        Ok(Self {
            stream: Either::Left(stream),
            transaction: 0,
            answer: vec![0; FC03_125_ANSWER],
        })
    }

    /// A connection over TLS with `connector`'s client certificate; `connect_to` with `tls`,
    /// else a plain one.
    pub(crate) async fn connect_to(
        addr: SocketAddr,
        tls: Option<&TlsConnector>,
    ) -> io::Result<Self> {
        let Some(connector) = tls else {
            return Self::connect(addr).await;
        };
        let stream = TcpStream::connect(addr).await?;
        stream.set_nodelay(true)?;
        let name = ServerName::try_from("localhost").map_err(io::Error::other)?;
        let stream = connector.connect(name, stream).await?;
        Ok(Self {
            stream: Either::Right(stream),
            transaction: 0,
            answer: vec![0; FC03_125_ANSWER],
        })
    }

    fn header(&mut self, unit: u8, pdu_len: u16) -> [u8; 7] {
        self.transaction = self.transaction.wrapping_add(1);
        let [t0, t1] = self.transaction.to_be_bytes();
        let [l0, l1] = (pdu_len + 1).to_be_bytes();
        [t0, t1, 0, 0, l0, l1, unit]
    }

    /// FC 03: reads 125 holding registers from 0 of `unit`; an exception or a malformed answer
    /// is an error.
    pub(crate) async fn read_125(&mut self, unit: u8) -> io::Result<()> {
        let h = self.header(unit, 5);
        let request = [h[0], h[1], h[2], h[3], h[4], h[5], h[6], 0x03, 0, 0, 0, 125];
        self.stream.write_all(&request).await?;
        self.stream.read_exact(&mut self.answer[..9]).await?;
        if self.answer.get(..2) != Some(&h[..2]) || self.answer.get(7..9) != Some(&[0x03, 250]) {
            return Err(io::Error::other(format!(
                "unexpected answer {:02X?}",
                self.answer.get(..9).unwrap_or_default()
            )));
        }
        self.stream
            .read_exact(&mut self.answer[9..FC03_125_ANSWER])
            .await?;
        Ok(())
    }

    /// `depth` FC 03 reads of 125 holding registers from 0 of `unit` written at once (a client
    /// that pipelines), then their answers, in order; an exception or a malformed answer is an
    /// error.
    pub(crate) async fn read_125_pipelined(&mut self, unit: u8, depth: usize) -> io::Result<()> {
        let mut requests = Vec::with_capacity(12 * depth);
        let mut ids = Vec::with_capacity(depth);
        for _ in 0..depth {
            let h = self.header(unit, 5);
            requests.extend_from_slice(&h);
            requests.extend_from_slice(&[0x03, 0, 0, 0, 125]);
            ids.push([h[0], h[1]]);
        }
        self.stream.write_all(&requests).await?;
        self.answer.resize(FC03_125_ANSWER * depth, 0);
        self.stream.read_exact(&mut self.answer).await?;
        for (answer, id) in self.answer.chunks_exact(FC03_125_ANSWER).zip(&ids) {
            if answer.get(..2) != Some(&id[..]) || answer.get(7..9) != Some(&[0x03, 250]) {
                return Err(io::Error::other(format!(
                    "unexpected answer {:02X?}",
                    answer.get(..9).unwrap_or_default()
                )));
            }
        }
        Ok(())
    }

    /// FC 03: reads one holding register of `unit`; an exception or a malformed answer is an
    /// error.
    pub(crate) async fn read_one(&mut self, unit: u8, address: u16) -> io::Result<u16> {
        let h = self.header(unit, 5);
        let [a0, a1] = address.to_be_bytes();
        let request = [h[0], h[1], h[2], h[3], h[4], h[5], h[6], 0x03, a0, a1, 0, 1];
        self.stream.write_all(&request).await?;
        // An exception answer is 9 bytes, a good one 11: read 9 first.
        let mut answer = [0u8; 11];
        self.stream.read_exact(&mut answer[..9]).await?;
        if answer.get(..2) != Some(&h[..2]) || answer.get(7..9) != Some(&[0x03, 2]) {
            return Err(io::Error::other(format!(
                "read answered {:02X?}",
                answer.get(..9).unwrap_or_default()
            )));
        }
        self.stream.read_exact(&mut answer[9..]).await?;
        Ok(u16::from_be_bytes([answer[9], answer[10]]))
    }

    /// FC 06: writes `value` to holding register `address` of `unit`; anything but the echo is
    /// an error.
    pub(crate) async fn write_one(&mut self, unit: u8, address: u16, value: u16) -> io::Result<()> {
        let h = self.header(unit, 5);
        let [a0, a1] = address.to_be_bytes();
        let [v0, v1] = value.to_be_bytes();
        let request = [
            h[0], h[1], h[2], h[3], h[4], h[5], h[6], 0x06, a0, a1, v0, v1,
        ];
        self.stream.write_all(&request).await?;
        let mut answer = [0u8; FC06_ANSWER];
        // An exception answer is 9 bytes: read the header and function first.
        self.stream.read_exact(&mut answer[..8]).await?;
        if answer.get(7) != Some(&0x06) {
            return Err(io::Error::other(format!("write answered {answer:02X?}")));
        }
        self.stream.read_exact(&mut answer[8..]).await?;
        if answer.get(..2) != Some(&h[..2]) || answer.get(8..) != request.get(8..) {
            return Err(io::Error::other(format!("write answered {answer:02X?}")));
        }
        Ok(())
    }
}
