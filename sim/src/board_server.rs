//! The simulated drive board on a serial port (`abvs sim board --serve`): the start-up roll, then both
//! eyes' encoder frames at a fixed rate while it executes the move commands read from the same port
//! ([`crate::servo_board::ServoBoard`], the protocol of `abvs_board::protocol`).
use std::io::{Read, Write};
use std::time::Duration;

use abvs_board::decoder::{CommandDecoder, CommandStats};
use abvs_board::error::BoardError;
use abvs_board::port::open_port;
use abvs_board::protocol::BoardFrame;
use abvs_board::stream::monotonic_ns;

use crate::servo_board::{Sample, ServoBoard};

/// What a served board did.
#[derive(Debug)]
pub struct ServeReport {
    /// Moves executed.
    pub executed: usize,
    /// Commands refused.
    pub refused: u64,
    /// Frames the wire did not take (lost, as on a UART).
    pub dropped: u64,
    /// What the command decoder saw.
    pub commands: CommandStats,
    /// The port error that ended the run early, if any.
    pub ended: Option<std::io::Error>,
}

impl std::fmt::Display for ServeReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "board: {} moves executed, {} refused; {} frames the wire did not take; commands: {} ok, {} CRC errors, {} unsupported{}",
            self.executed,
            self.refused,
            self.dropped,
            self.commands.commands,
            self.commands.crc_errors,
            self.commands.unsupported,
            self.ended.as_ref().map(|e| format!("; port closed ({e})")).unwrap_or_default()
        )
    }
}

/// Serves the board `seed` on `port_name`: the start-up roll, then both eyes' encoder frames at `rate_hz`
/// while executing the move commands read from the same port, for `seconds`.
pub fn serve_board(port_name: &str, seed: u64, rate_hz: f64, seconds: f64) -> Result<ServeReport, BoardError> {
    let mut port = open_port(port_name, 1_000_000)?;
    port.set_timeout(Duration::from_millis(1)).map_err(|source| BoardError::Open { port: port_name.into(), source })?;
    let mut board = ServoBoard::from_seed(seed);
    board.roll.rate_hz = rate_hz;
    let t0 = monotonic_ns();
    let now_us = || ((monotonic_ns() - t0) / 1000) as u64 + 1000;
    let mut decoder = CommandDecoder::new();
    let mut seq = 0u16;
    let mut buf = [0u8; 1024];
    let mut dropped = 0u64;
    // A frame the wire cannot take now is lost (counted), as on a UART; other errors end the run.
    let mut send = |port: &mut Box<dyn serialport::SerialPort>, s: Sample| -> std::io::Result<()> {
        let f = BoardFrame { seq, board_time_us: s.0, eye: s.1, counts: s.2, index: s.3 };
        seq = seq.wrapping_add(1);
        match port.write_all(&f.encode()) {
            Err(e) if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock) => {
                dropped += 1;
                Ok(())
            }
            r => r,
        }
    };
    let mut poll = |port: &mut Box<dyn serialport::SerialPort>, board: &mut ServoBoard| -> std::io::Result<()> {
        if port.bytes_to_read().unwrap_or(0) > 0 {
            let n =
                port.read(&mut buf)
                    .or_else(|e| if e.kind() == std::io::ErrorKind::TimedOut { Ok(0) } else { Err(e) })?;
            for c in decoder.feed(&buf[..n]) {
                board.command(&c, now_us());
            }
        }
        Ok(())
    };
    let wait_until = |t_us: u64| {
        let now = now_us();
        if t_us > now {
            std::thread::sleep(Duration::from_micros((t_us - now).min(2000)));
        }
    };
    let end_us = (seconds * 1e6) as u64 + 1000;
    let mut ended = None;
    let startup = board.startup(1000);
    for s in startup {
        while now_us() < s.0 {
            wait_until(s.0);
        }
        if let Err(e) = send(&mut port, s) {
            ended = Some(e);
            break;
        }
    }
    let period_us = (1e6 / rate_hz).round().max(1.0) as u64;
    let mut next = board.startup_end_us(1000);
    while ended.is_none() && next < end_us {
        while now_us() < next {
            wait_until(next);
        }
        if let Err(e) = poll(&mut port, &mut board) {
            ended = Some(e);
            break;
        }
        for eye in 0..2 {
            let s = board.sample(eye, next);
            if let Err(e) = send(&mut port, s) {
                ended = Some(e);
                break;
            }
        }
        next += period_us;
    }
    let _ = port.flush();
    Ok(ServeReport { executed: board.executed.len(), refused: board.refused, dropped, commands: decoder.stats, ended })
}
