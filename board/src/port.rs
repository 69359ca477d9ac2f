//! The serial port the board link runs over (a real one, or a pseudo-terminal in tests and simulations).
use crate::error::BoardError;

/// Opens a serial port for the board link (200 ms read timeout).
pub fn open_port(path: &str, baud: u32) -> Result<Box<dyn serialport::SerialPort>, BoardError> {
    serialport::new(path, baud)
        .timeout(std::time::Duration::from_millis(200))
        .open()
        .map_err(|source| BoardError::Open { port: path.to_string(), source })
}
