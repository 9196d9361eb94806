//! The publish node's default zenoh session cannot be reached from another host. The other host
//! is a network namespace joined to this one by a veth pair; a listener open to every address
//! is reachable from it (so the check can see reachability), the session's listener is not.
//!
//! Making a namespace needs root and `ip`; where it cannot be made, the test says so and passes.

use std::process::Command;

use neuspike_publish::{PublishConfig, Publisher};

fn ip(args: &[&str]) -> bool {
    Command::new("ip")
        .args(args)
        .output()
        .is_ok_and(|o| o.status.success())
}

/// A namespace `far` with a veth pair to this one: this side `near_addr`, that side `.2`.
struct FarHost {
    ns: String,
    near: String,
    near_addr: String,
}

impl FarHost {
    fn make() -> Result<Self, String> {
        let id = std::process::id();
        let ns = format!("neuspike-far-{id}");
        let (near, far) = (format!("nsn{id}"), format!("nsf{id}"));
        let subnet = format!("10.215.{}", id % 250);
        if !ip(&["netns", "add", &ns]) {
            return Err("`ip netns add` failed (root and iproute2 are needed)".into());
        }
        let host = FarHost {
            ns: ns.clone(),
            near: near.clone(),
            near_addr: format!("{subnet}.1"),
        };
        let ok = ip(&["link", "add", &near, "type", "veth", "peer", "name", &far])
            && ip(&["link", "set", &far, "netns", &ns])
            && ip(&["addr", "add", &format!("{subnet}.1/24"), "dev", &near])
            && ip(&["link", "set", &near, "up"])
            && ip(&[
                "-n",
                &ns,
                "addr",
                "add",
                &format!("{subnet}.2/24"),
                "dev",
                &far,
            ])
            && ip(&["-n", &ns, "link", "set", &far, "up"])
            && ip(&["-n", &ns, "link", "set", "lo", "up"]);
        if ok {
            Ok(host)
        } else {
            Err("cannot set up the veth pair".into())
        }
    }

    /// Whether a TCP connection from the far host to `port` on this host succeeds.
    fn reaches(&self, port: u16) -> bool {
        let script = format!("exec 3<>/dev/tcp/{}/{port}", self.near_addr);
        Command::new("ip")
            .args([
                "netns", "exec", &self.ns, "timeout", "3", "bash", "-c", &script,
            ])
            .output()
            .is_ok_and(|o| o.status.success())
    }
}

impl Drop for FarHost {
    fn drop(&mut self) {
        ip(&["link", "del", &self.near]);
        ip(&["netns", "del", &self.ns]);
    }
}

#[test]
fn the_default_session_cannot_be_reached_from_another_host() {
    let far = match FarHost::make() {
        Ok(f) => f,
        Err(why) => {
            eprintln!("SKIPPED: a second network namespace cannot be made here: {why}");
            return;
        }
    };
    // The check can see a listener that is reachable.
    let open = std::net::TcpListener::bind("0.0.0.0:0").expect("an open listener");
    let open_port = open.local_addr().expect("addr").port();
    assert!(
        far.reaches(open_port),
        "the far host cannot reach an open listener"
    );

    let cfg = PublishConfig {
        graph: "reach".into(),
        ros2: vec![],
        ros2_events: vec![],
        ros_domain: 0,
        ros_node: "neuspike".into(),
        ros_namespace: "/".into(),
        frame_id: "f".into(),
        congestion: neuspike_publish::Congestion::Block,
        linger_s: 0.0,
        mcap: None,
        zenoh: neuspike_net::ZenohArgs::default(),
    };
    let publisher = Publisher::open(&cfg, &["tfp".to_string()]).expect("publisher");
    let locators = publisher.locators();
    assert!(!locators.is_empty(), "the session listens somewhere");
    for l in &locators {
        assert!(
            l.starts_with("tcp/127.0.0.1:"),
            "listens beyond loopback: {l}"
        );
        let port: u16 = l
            .rsplit(':')
            .next()
            .and_then(|p| p.parse().ok())
            .expect("a port");
        assert!(!far.reaches(port), "{l} is reachable from another host");
    }
}
