//! The two-machine rig of `examples/mtls/` (docs/untrusted.md), its configuration files as they
//! ship, on loopback: the camera machine listens over mutual TLS, the compute machine dials it,
//! and certificates come from the rig's own authority. A peer without such a certificate opens
//! no link, so it can neither publish into the graph nor read from it; a peer with one that is
//! not the compute machine (a viewer of the same rig) opens a link but may neither publish on
//! the camera keys nor receive them.

use std::path::Path;
use std::time::{Duration, Instant};

use neuspike_net::session::ZenohArgs;
use rcgen::{BasicConstraints, CertificateParams, DnType, IsCa, Issuer, KeyPair};
use zenoh::Wait;

const KEY: &str = "neuspike/camera/spikes";

/// A certificate authority: its PEM certificate and what signs with it.
struct Authority {
    pem: String,
    issuer: Issuer<'static, KeyPair>,
}

fn authority(name: &str) -> Authority {
    let mut params = CertificateParams::new(Vec::<String>::new()).expect("params");
    params.distinguished_name.push(DnType::CommonName, name);
    params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    let key = KeyPair::generate().expect("key");
    let cert = params.self_signed(&key).expect("CA certificate");
    Authority {
        pem: cert.pem(),
        issuer: Issuer::new(params, key),
    }
}

/// Writes `<name>.pem` and `<name>.key` in `dir`: a certificate for the host `localhost` (and the
/// address `at`, where given) whose common name is `name`, signed by `ca`.
fn machine(dir: &Path, ca: &Authority, name: &str, at: Option<&str>) {
    let hosts: Vec<String> = ["localhost"]
        .into_iter()
        .chain(at)
        .map(String::from)
        .collect();
    let mut params = CertificateParams::new(hosts).expect("params");
    params.distinguished_name.push(DnType::CommonName, name);
    let key = KeyPair::generate().expect("key");
    let cert = params.signed_by(&key, &ca.issuer).expect("certificate");
    std::fs::write(dir.join(format!("{name}.pem")), cert.pem()).expect("write");
    std::fs::write(dir.join(format!("{name}.key")), key.serialize_pem()).expect("write");
}

/// The session of `examples/mtls/<file>` as it ships, with the certificate files of `name` in
/// `dir`, the authority's certificate `ca` (a file in `dir`) and the endpoints given instead of
/// the example's host names.
fn session(
    dir: &Path,
    file: &str,
    name: &str,
    ca: &str,
    listen: &[String],
    connect: &[String],
) -> zenoh::Session {
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/mtls")
        .join(file);
    let mut c = ZenohArgs {
        zenoh_config: Some(shipped),
        ..ZenohArgs::default()
    }
    .config()
    .expect("the shipped configuration");
    let path = |f: String| format!("{:?}", dir.join(f).display().to_string());
    let json = |v: &[String]| format!("{v:?}");
    for (k, v) in [
        (
            "transport/link/tls/root_ca_certificate",
            path(ca.to_string()),
        ),
        (
            "transport/link/tls/listen_certificate",
            path(format!("{name}.pem")),
        ),
        (
            "transport/link/tls/listen_private_key",
            path(format!("{name}.key")),
        ),
        (
            "transport/link/tls/connect_certificate",
            path(format!("{name}.pem")),
        ),
        (
            "transport/link/tls/connect_private_key",
            path(format!("{name}.key")),
        ),
        ("listen/endpoints", json(listen)),
        ("connect/endpoints", json(connect)),
    ] {
        c.insert_json5(k, &v)
            .unwrap_or_else(|e| panic!("{k} = {v}: {e}"));
    }
    zenoh::open(c).wait().expect("the session opens")
}

/// What `sub` received within `wait`, as text.
fn received(
    sub: &zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    wait: Duration,
) -> Vec<String> {
    let deadline = Instant::now() + wait;
    let mut out = Vec::new();
    while let Ok(Some(s)) = sub.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        out.push(String::from_utf8_lossy(&s.payload().to_bytes()).into_owned());
    }
    out
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port()
}

#[test]
fn only_the_rigs_compute_machine_reads_and_only_its_camera_publishes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rig = authority("rig");
    std::fs::write(dir.path().join("rig-ca.pem"), &rig.pem).expect("write");
    for name in ["camera", "compute", "viewer"] {
        machine(dir.path(), &rig, name, None);
    }
    // An intruder with a certificate of its own authority, named as the compute machine.
    let own = authority("intruder");
    std::fs::write(dir.path().join("own-ca.pem"), &own.pem).expect("write");
    let intruder_dir = dir.path().join("intruder");
    std::fs::create_dir(&intruder_dir).expect("mkdir");
    machine(&intruder_dir, &own, "compute", None);
    std::fs::copy(
        dir.path().join("own-ca.pem"),
        intruder_dir.join("own-ca.pem"),
    )
    .expect("copy");

    let port = free_port();
    let at = vec![format!("tls/localhost:{port}")];
    let camera = session(dir.path(), "camera.json5", "camera", "rig-ca.pem", &at, &[]);
    let compute = session(
        dir.path(),
        "compute.json5",
        "compute",
        "rig-ca.pem",
        &[],
        &at,
    );
    let inbox = compute.declare_subscriber(KEY).wait().expect("subscriber");
    let publisher = camera.declare_publisher(KEY).wait().expect("publisher");
    let deadline = Instant::now() + Duration::from_secs(20);
    while !publisher
        .matching_status()
        .wait()
        .expect("status")
        .matching()
    {
        assert!(
            Instant::now() < deadline,
            "the compute machine never subscribed over TLS"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    publisher.put("genuine 1").wait().expect("put");
    assert_eq!(received(&inbox, Duration::from_secs(2)), ["genuine 1"]);

    // A viewer of the same rig: a link opens, but it may neither publish nor read the camera.
    let viewer = session(
        dir.path(),
        "compute.json5",
        "viewer",
        "rig-ca.pem",
        &[],
        &at,
    );
    // An intruder with its own authority's certificate: no link opens at all.
    let intruder = session(
        &intruder_dir,
        "compute.json5",
        "compute",
        "own-ca.pem",
        &[],
        &at,
    );
    // And one without TLS, dialling the same port in plain TCP.
    let plain = zenoh::open({
        let mut c = ZenohArgs {
            connect: vec![format!("tcp/127.0.0.1:{port}")],
            ..ZenohArgs::default()
        }
        .config()
        .expect("config");
        c.insert_json5("listen/endpoints", "[]").expect("listen");
        c
    })
    .wait()
    .expect("the session opens");
    let deadline = Instant::now() + Duration::from_secs(20);
    while camera.info().peers_zid().wait().count() < 2 {
        assert!(
            Instant::now() < deadline,
            "the viewer never linked to the camera"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let linked = |s: &zenoh::Session| s.info().peers_zid().wait().count();
    assert_eq!(
        linked(&intruder),
        0,
        "a certificate of another authority linked"
    );
    assert_eq!(linked(&plain), 0, "plain TCP linked to a TLS port");
    let watchers: Vec<_> = [&viewer, &intruder, &plain]
        .iter()
        .map(|s| {
            s.declare_subscriber("neuspike/**")
                .wait()
                .expect("subscriber")
        })
        .collect();
    for (s, who) in [
        (&viewer, "viewer"),
        (&intruder, "intruder"),
        (&plain, "plain"),
    ] {
        s.put(KEY, format!("forged by {who}")).wait().expect("put");
    }
    std::thread::sleep(Duration::from_millis(500));
    publisher.put("genuine 2").wait().expect("put");
    assert_eq!(received(&inbox, Duration::from_secs(2)), ["genuine 2"]);
    // (a session hears its own puts: only the camera's count)
    for (w, who) in watchers.iter().zip(["viewer", "intruder", "plain"]) {
        let got = received(w, Duration::from_millis(200));
        assert!(
            !got.iter().any(|m| m.starts_with("genuine")),
            "{who} read the camera: {got:?}"
        );
    }
}

/// Two network namespaces joined by a veth pair: the camera machine at `.1`, the other at `.2`.
/// Removed, with what still runs in them, when dropped.
struct TwoHosts {
    camera: String,
    other: String,
    camera_addr: String,
}

fn ip(args: &[&str]) -> bool {
    std::process::Command::new("ip")
        .args(args)
        .output()
        .is_ok_and(|o| o.status.success())
}

impl TwoHosts {
    fn make() -> Result<Self, String> {
        let id = std::process::id();
        let subnet = format!("10.214.{}", id % 250);
        let hosts = TwoHosts {
            camera: format!("neuspike-tls-cam-{id}"),
            other: format!("neuspike-tls-net-{id}"),
            camera_addr: format!("{subnet}.1"),
        };
        if !ip(&["netns", "add", &hosts.camera]) || !ip(&["netns", "add", &hosts.other]) {
            return Err("`ip netns add` failed (root and iproute2 are needed)".into());
        }
        let (a, b) = (format!("ntc{id}"), format!("ntn{id}"));
        let ok = ip(&["link", "add", &a, "type", "veth", "peer", "name", &b])
            && ip(&["link", "set", &a, "netns", &hosts.camera])
            && ip(&["link", "set", &b, "netns", &hosts.other]);
        if !ok {
            return Err("cannot make the veth pair".into());
        }
        for (ns, dev, addr) in [
            (&hosts.camera, &a, format!("{subnet}.1/24")),
            (&hosts.other, &b, format!("{subnet}.2/24")),
        ] {
            let ok = ip(&["-n", ns, "addr", "add", &addr, "dev", dev])
                && ip(&["-n", ns, "link", "set", "lo", "up"])
                && ip(&["-n", ns, "link", "set", dev, "up"]);
            if !ok {
                return Err(format!("cannot bring up {dev} in {ns}"));
            }
        }
        Ok(hosts)
    }
}

impl Drop for TwoHosts {
    fn drop(&mut self) {
        for ns in [&self.camera, &self.other] {
            if let Ok(o) = std::process::Command::new("ip")
                .args(["netns", "pids", ns])
                .output()
            {
                for pid in String::from_utf8_lossy(&o.stdout).split_whitespace() {
                    let _ = std::process::Command::new("kill")
                        .args(["-9", pid])
                        .status();
                }
            }
            ip(&["netns", "del", ns]);
        }
    }
}

const ROLE: &str = "NEUSPIKE_TLS_ROLE";

/// One machine of the two-namespace test, run as a child of it (`ROLE` set): the camera publishes
/// for 8 s; the others listen for 6 s, the intruders putting forged chunks all along, then print
/// what they received and how many peers they linked to. Without `ROLE`, nothing.
#[test]
fn tls_role() {
    let Ok(role) = std::env::var(ROLE) else {
        return;
    };
    let dir = std::path::PathBuf::from(std::env::var("NEUSPIKE_TLS_DIR").expect("dir"));
    let at = vec![std::env::var("NEUSPIKE_TLS_AT").expect("endpoint")];
    let s = match role.as_str() {
        "camera" => session(&dir, "camera.json5", "camera", "rig-ca.pem", &at, &[]),
        "compute" => session(&dir, "compute.json5", "compute", "rig-ca.pem", &[], &at),
        "intruder" => session(
            &dir.join("intruder"),
            "compute.json5",
            "compute",
            "own-ca.pem",
            &[],
            &at,
        ),
        other => panic!("no role {other}"),
    };
    if role == "camera" {
        let p = s.declare_publisher(KEY).wait().expect("publisher");
        for i in 0..80 {
            p.put(format!("genuine {i}")).wait().expect("put");
            std::thread::sleep(Duration::from_millis(100));
        }
        println!("ROLE camera sent=80");
        return;
    }
    let sub = s
        .declare_subscriber("neuspike/camera/**")
        .wait()
        .expect("subscriber");
    let deadline = Instant::now() + Duration::from_secs(6);
    let mut got = Vec::new();
    while Instant::now() < deadline {
        if role == "intruder" {
            let _ = s.put(KEY, "forged").wait();
        }
        got.extend(received(&sub, Duration::from_millis(100)));
    }
    let genuine = got.iter().filter(|g| g.starts_with("genuine")).count();
    let forged = got.len() - genuine;
    let peers = s.info().peers_zid().wait().count();
    println!("ROLE {role} genuine={genuine} forged={forged} peers={peers}");
}

/// The rig across a network link: the camera machine in one namespace, the compute machine and an
/// intruder (a certificate of its own authority, named `compute`) in the other. The compute machine
/// receives the camera's chunks; the intruder links to nothing, reads nothing, and none of its
/// forged chunks reach the compute machine. Where namespaces cannot be made (no root), the test
/// says so and passes.
#[test]
fn across_a_network_link_an_unauthenticated_peer_neither_publishes_nor_reads() {
    let hosts = match TwoHosts::make() {
        Ok(h) => h,
        Err(why) => {
            eprintln!("SKIPPED: network namespaces cannot be made here: {why}");
            return;
        }
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let rig = authority("rig");
    std::fs::write(dir.path().join("rig-ca.pem"), &rig.pem).expect("write");
    for name in ["camera", "compute"] {
        machine(dir.path(), &rig, name, Some(&hosts.camera_addr));
    }
    let own = authority("intruder");
    let intruder_dir = dir.path().join("intruder");
    std::fs::create_dir(&intruder_dir).expect("mkdir");
    std::fs::write(intruder_dir.join("own-ca.pem"), &own.pem).expect("write");
    machine(&intruder_dir, &own, "compute", None);
    let at = format!("tls/{}:7450", hosts.camera_addr);
    let exe = std::env::current_exe().expect("the test program");
    let spawn = |ns: &str, role: &str| {
        std::process::Command::new("ip")
            .args(["netns", "exec", ns])
            .arg(&exe)
            .args(["--exact", "tls_role", "--nocapture", "--test-threads", "1"])
            .env(ROLE, role)
            .env("NEUSPIKE_TLS_DIR", dir.path())
            .env("NEUSPIKE_TLS_AT", &at)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("spawn a role")
    };
    let camera = spawn(&hosts.camera, "camera");
    std::thread::sleep(Duration::from_millis(500));
    let compute = spawn(&hosts.other, "compute");
    let intruder = spawn(&hosts.other, "intruder");
    let line = |child: std::process::Child, role: &str| -> String {
        let out = child.wait_with_output().expect("a role ran");
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "{role}: {text}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        text.lines()
            .find_map(|l| {
                l.split_once(&format!("ROLE {role} "))
                    .map(|(_, r)| r.to_string())
            })
            .unwrap_or_else(|| panic!("{role} said nothing: {text}"))
    };
    let (compute, intruder) = (line(compute, "compute"), line(intruder, "intruder"));
    let _ = line(camera, "camera");
    let field = |l: &str, k: &str| -> usize {
        l.split_whitespace()
            .find_map(|f| f.strip_prefix(&format!("{k}=")))
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{k} in {l}"))
    };
    assert!(field(&compute, "genuine") > 20, "compute: {compute}");
    assert_eq!(field(&compute, "forged"), 0, "compute: {compute}");
    assert_eq!(field(&compute, "peers"), 1, "compute: {compute}");
    assert_eq!(
        (field(&intruder, "genuine"), field(&intruder, "peers")),
        (0, 0),
        "intruder: {intruder}"
    );
}
