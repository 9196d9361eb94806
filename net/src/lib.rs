//! neuspike on the network, for the nodes that publish to it and the sources that read from it.
//!
//! - [`session`]: the zenoh session every such node opens, safe by default: peer mode, listening
//!   on loopback only, dialling a router on `tcp/127.0.0.1:7447` (rmw_zenoh's `rmw_zenohd`)
//!   when one runs, multicast scouting off; anything else from a zenoh JSON5 file.
//! - [`remote`]: neuspike's own messages (Arrow IPC, `neuspike_schemas::ipc`) taken off a zenoh
//!   key, in order, with every lost message counted by its sequence number and a silent
//!   publisher reported, never waited for forever.
//! - [`ros2`]: what a ROS 2 system running rmw_zenoh needs and sends: data keys, liveliness
//!   tokens, attachments, `sensor_msgs/msg/Image` and `event_camera_msgs/msg/EventPacket` in CDR,
//!   written and read (every length checked against the bytes before it is used).

pub mod queue;
pub mod remote;
pub mod ros2;
pub mod session;

pub use remote::{Remote, RemoteError, Taken, put_message};
pub use session::{SessionError, ZenohArgs};
