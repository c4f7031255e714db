//! The real bus: what `climbsim tap` sees between an unchanged controller and real servos.
//! [`stream`] frames each direction with its bytes' times and keeps what is in no packet,
//! [`pairing`] pairs each instruction with its replies and names the servos that did not
//! answer, [`transcript`] is the file it writes (marked as real), [`timing`] the report of the
//! servos' reply latency. All sans-IO: the bridge itself is `runner::tap`.

pub mod compare;
pub mod fit;
pub mod pairing;
pub mod stream;
pub mod timing;
pub mod transcript;

pub use pairing::{Event, Pairing, Seen, SeenReply};
pub use timing::{TimingReport, TimingTally};
pub use transcript::{FORMAT, RealHeader, RealRecord, RealTranscript, Side, VERSION};
