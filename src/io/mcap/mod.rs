//! MCAP, record by record: [`read`] streams records and the summary in bounded memory,
//! [`chunk`] decodes one chunk's records, [`salvage`] reads what damaged logs still hold,
//! [`record`] parses and checks single records,
//! [`write`](mod@write) writes records (chunks, indexes, summary), and [`log`] ties them into the input
//! catalog and the output log that `register` copies input messages into.

pub mod chunk;
pub mod log;
pub mod read;
pub mod record;
pub mod salvage;
pub mod write;
