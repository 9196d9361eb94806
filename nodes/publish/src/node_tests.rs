//! The node driven through its `run` loop with canned inputs, heard by a zenoh subscriber on
//! loopback.

use std::time::Duration;

use super::*;
use ndarray::Array2;
use neuspike_net::ros2::{IMAGE_HASH, IMAGE_TYPE};
use neuspike_publish::image::{self, Encoding};
use neuspike_runtime::testing::CannedInputs;
use neuspike_schemas::{Frame, FrameKind, Message, is_end_of_stream};
use zenoh::Wait;

fn frame(seq: u64) -> Frame {
    Frame {
        kind: FrameKind::Reconstruction,
        method: "tfp".into(),
        t_ref_ns: 1_000_000 * seq as i64,
        compute_ns: 5,
        chosen: None,
        budget_ns: None,
        seq,
        data: Array2::from_shape_fn((6, 8), |(y, x)| (x + 8 * y) as f32 / 47.0),
    }
}

/// A free TCP port on loopback.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

#[test]
fn frames_reach_zenoh_as_arrow_and_ros2_images_with_their_attachment_and_tokens() {
    let dir = tempfile::tempdir().expect("tempdir");
    // The listener: a peer on loopback, as a robot's process would be.
    let port = free_port();
    let mut conf = zenoh::Config::default();
    conf.insert_json5("mode", "\"peer\"").expect("mode");
    conf.insert_json5("listen/endpoints", &format!("[\"tcp/127.0.0.1:{port}\"]"))
        .expect("listen");
    conf.insert_json5("scouting/multicast/enabled", "false")
        .expect("scouting");
    let sub_session = zenoh::open(conf).wait().expect("subscriber session");
    let arrow_sub = sub_session
        .declare_subscriber("neuspike/test/tfp")
        .wait()
        .expect("arrow subscriber");
    let ros_key = format!("0/neuspike/tfp/{IMAGE_TYPE}/{IMAGE_HASH}");
    let ros_sub = sub_session
        .declare_subscriber(ros_key.clone())
        .wait()
        .expect("ros subscriber");

    let cfg = PublishConfig {
        graph: "test".into(),
        ros2: vec![neuspike_publish::RosTopic {
            input: "tfp".into(),
            topic: "/neuspike/tfp".into(),
            encoding: Encoding::Mono16,
        }],
        ros2_events: vec![],
        ros_domain: 0,
        ros_node: "neuspike".into(),
        ros_namespace: "/".into(),
        frame_id: "spike_camera".into(),
        congestion: neuspike_publish::Congestion::Block,
        linger_s: 0.0,
        mcap: None,
        zenoh: neuspike_net::ZenohArgs {
            listen: vec!["tcp/127.0.0.1:0".into()],
            connect: vec![format!("tcp/127.0.0.1:{port}")],
            ..Default::default()
        },
    };
    let inputs = vec!["tfp".to_string()];
    let publisher = Publisher::open(&cfg, &inputs).expect("publisher");
    let zid = publisher.zid();
    // Declarations travel between the peers before the first sample.
    std::thread::sleep(Duration::from_millis(500));

    // The tokens ROS 2 tools read: the node and its publisher.
    let tokens: Vec<String> = sub_session
        .liveliness()
        .get("@ros2_lv/**")
        .wait()
        .expect("liveliness query")
        .iter()
        .filter_map(|r| r.into_result().ok().map(|s| s.key_expr().to_string()))
        .collect();
    assert!(
        tokens.contains(&format!("@ros2_lv/0/{zid}/0/0/NN/%/%/neuspike")),
        "{tokens:?}"
    );
    assert!(
        tokens.iter().any(|t| t.starts_with(&format!(
            "@ros2_lv/0/{zid}/0/1/MP/%/%/neuspike/%neuspike%tfp/{IMAGE_TYPE}/{IMAGE_HASH}/"
        ))),
        "{tokens:?}"
    );

    let mut c = CannedInputs::new(dir.path());
    c.message("tfp", &frame(0)).expect("f0");
    c.message("tfp", &frame(1)).expect("f1");
    c.end::<Frame>("tfp", 2).expect("end");
    c.run(|node, events| run(node, events, publisher, &inputs))
        .expect("run");

    // Arrow IPC: both frames, whole, then the marker.
    let mut got = Vec::new();
    while let Ok(Some(s)) = arrow_sub.recv_timeout(Duration::from_secs(2)) {
        let bytes = s.payload().to_bytes();
        let (_, meta, data) = neuspike_schemas::ipc::decode(&bytes).expect("decode");
        if is_end_of_stream(&meta) == Some(2) {
            break;
        }
        got.push(Frame::from_arrow(&meta, &data).expect("a frame"));
    }
    assert_eq!(got, [frame(0), frame(1)]);

    // ROS 2: the images in CDR, each with rmw_zenoh's 33-byte attachment.
    for seq in 0..2u64 {
        let s = ros_sub
            .recv_timeout(Duration::from_secs(2))
            .expect("recv")
            .expect("an image");
        let expected = image::frame_image(
            &frame(seq),
            frame(seq).t_ref_ns,
            "spike_camera",
            Encoding::Mono16,
        );
        assert_eq!(s.payload().to_bytes().as_ref(), expected.as_slice());
        let a = s.attachment().expect("attachment").to_bytes();
        assert_eq!(a.len(), 33);
        assert_eq!(a[..8], (seq as i64 + 1).to_le_bytes());
        assert_eq!(a[16], 16);
    }
}
