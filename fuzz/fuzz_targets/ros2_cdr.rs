//! ROS 2 samples as they arrive over rmw_zenoh: the CDR of `sensor_msgs/msg/Image` and
//! `event_camera_msgs/msg/EventPacket`, and rmw_zenoh's attachment. Any bytes give a packet or an
//! error naming the byte, never a panic, and no length in them makes the reader allocate. Every
//! packet that parses goes through the source's packet decoder (EVT 3.0 and `mono`), split in
//! two at a point the input chooses, so that the decoder's state crosses a packet boundary; its
//! batches must hold valid events that tile time.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| neuspike_fuzz::ros2::ros2_cdr(data));
