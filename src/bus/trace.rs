//! `--trace-bus`: every transaction as JSON lines (time, direction, hex, decoded).

use std::io::Write;

use serde_json::{Value, json};

use super::Transaction;

fn hex(bytes: &[u8]) -> String {
    let mut out = String::with_capacity(bytes.len() * 3);
    for (i, b) in bytes.iter().enumerate() {
        if i > 0 {
            out.push(' ');
        }
        out.push_str(&format!("{b:02X}"));
    }
    out
}

/// The JSON lines for one transaction: the instruction, then each reply.
pub fn transaction_json(transaction: &Transaction) -> Vec<Value> {
    let mut lines = Vec::with_capacity(1 + transaction.replies.len());
    let decoded = match &transaction.instruction {
        Ok(instruction) => json!({ "instruction": instruction.name(), "detail": format!("{instruction:?}") }),
        Err(error) => json!({ "instruction": format!("0x{:02X}", transaction.packet.instruction), "error": error.to_string() }),
    };
    lines.push(json!({
        "t": transaction.received_at.as_secs_f64(),
        "wire_end": transaction.instruction_end.as_secs_f64(),
        "dir": "controller->servos",
        "id": transaction.packet.id,
        "hex": hex(&transaction.packet.bytes),
        "decoded": decoded,
    }));
    for reply in &transaction.replies {
        let error = reply.bytes.get(8).copied();
        lines.push(json!({
            "t": reply.end.as_secs_f64(),
            "wire_start": reply.start.as_secs_f64(),
            "dir": "servos->controller",
            "from": reply.from,
            "hex": hex(&reply.bytes),
            "decoded": { "status_error": error, "bytes": reply.bytes.len() },
        }));
    }
    lines
}

/// Writes transactions to a file (or any writer) as JSON lines.
pub struct TraceWriter {
    out: Box<dyn Write + Send>,
}

impl TraceWriter {
    pub fn new(out: Box<dyn Write + Send>) -> Self {
        Self { out }
    }

    pub fn record(&mut self, transaction: &Transaction) -> std::io::Result<()> {
        for line in transaction_json(transaction) {
            serde_json::to_writer(&mut self.out, &line)?;
            self.out.write_all(b"\n")?;
        }
        self.out.flush()
    }
}
