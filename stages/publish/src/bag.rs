//! A run recorded as a ROS 2 bag: an MCAP file as rosbag2's MCAP storage writes it (profile
//! `ros2`, schemas in `ros2msg`, messages in `cdr`), so that `ros2 bag play run.mcap`, rosbags
//! and Foxglove read it. Every ROS 2 topic the node publishes is a channel with the same CDR
//! bytes; neuspike's own messages are channels too, named by their zenoh key, their samples the
//! same Arrow IPC bytes (message encoding `neuspike/messages/v1`).
//!
//! The file is written as it goes, as `<name>.partial`, and finished (its summary and index,
//! synced) and renamed to its name when the node ends: a bag under its own name is whole. A node
//! killed or failed before that leaves `<name>.partial`, whose messages a reader still recovers
//! by scanning.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// The message encoding of neuspike's own messages in the bag.
pub const NEUSPIKE_ENCODING: &str = "neuspike/messages/v1";

const HEADER_DEFS: &str =
    "================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
";

/// `sensor_msgs/msg/Image`'s definition as rosbag2 stores it, its dependencies appended.
pub fn image_definition() -> String {
    format!(
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n{HEADER_DEFS}"
    )
}

/// `event_camera_msgs/msg/EventPacket`'s definition, its dependencies appended.
pub fn event_packet_definition() -> String {
    format!(
        "std_msgs/Header header\nuint32 height\nuint32 width\nuint64 seq\nuint64 time_base\nstring encoding\nbool is_bigendian\nuint8[] events\n{HEADER_DEFS}"
    )
}

/// Why the bag could not be written.
#[derive(Debug, thiserror::Error)]
#[error("{path}: cannot write the bag: {reason}")]
pub struct BagError {
    path: PathBuf,
    reason: String,
}

/// An MCAP file being written.
pub struct Bag {
    /// Its name once finished.
    path: PathBuf,
    /// Where it is written until then ([`partial_path`]).
    partial: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    channels: HashMap<String, (u16, u32)>,
    messages: u64,
}

impl Bag {
    /// Starts the bag `path` (its folder too): written as [`partial_path`] until
    /// [`Self::finish`].
    ///
    /// # Errors
    /// The file cannot be created.
    pub fn create(path: &Path) -> Result<Self, BagError> {
        let err = |e: &dyn std::fmt::Display| BagError {
            path: path.to_path_buf(),
            reason: e.to_string(),
        };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| err(&e))?;
        }
        let partial = partial_path(path);
        let file = File::create(&partial).map_err(|e| err(&e))?;
        let writer = mcap::WriteOptions::new()
            .profile("ros2")
            .compression(None)
            .create(BufWriter::new(file))
            .map_err(|e| err(&e))?;
        Ok(Bag {
            path: path.to_path_buf(),
            partial,
            writer,
            channels: HashMap::new(),
            messages: 0,
        })
    }

    fn err(&self, e: impl std::fmt::Display) -> BagError {
        BagError {
            path: self.path.clone(),
            reason: e.to_string(),
        }
    }

    /// The channel of `topic`, added on first use with the schema `(name, definition)` (none for
    /// neuspike's own messages) and `encoding`.
    fn channel(
        &mut self,
        topic: &str,
        schema: Option<(&str, &str)>,
        encoding: &str,
    ) -> Result<u16, BagError> {
        if let Some(&(id, _)) = self.channels.get(topic) {
            return Ok(id);
        }
        let schema_id = match schema {
            Some((name, def)) => self
                .writer
                .add_schema(name, "ros2msg", def.as_bytes())
                .map_err(|e| self.err(e))?,
            None => 0,
        };
        let mut meta = BTreeMap::new();
        if schema.is_some() {
            // What rosbag2 stores per topic: the offered QoS, reliable and volatile, depth 10.
            meta.insert(
                "offered_qos_profiles".to_string(),
                "- history: 1\n  depth: 10\n  reliability: 1\n  durability: 2\n".to_string(),
            );
        }
        let id = self
            .writer
            .add_channel(schema_id, topic, encoding, &meta)
            .map_err(|e| self.err(e))?;
        self.channels.insert(topic.to_string(), (id, 0));
        Ok(id)
    }

    /// Records one ROS 2 message (CDR) on `topic` of type `type_name`
    /// (`sensor_msgs/msg/Image`) with the definition `definition`, at `log_ns` (ns since the
    /// epoch) and published at `publish_ns`.
    ///
    /// # Errors
    /// The file could not be written.
    pub fn ros2(
        &mut self,
        topic: &str,
        type_name: &str,
        definition: &str,
        cdr: &[u8],
        log_ns: i64,
        publish_ns: i64,
    ) -> Result<(), BagError> {
        let id = self.channel(topic, Some((type_name, definition)), "cdr")?;
        self.write(topic, id, cdr, log_ns, publish_ns)
    }

    /// Records one of neuspike's messages (Arrow IPC bytes) on the channel named `key`.
    ///
    /// # Errors
    /// The file could not be written.
    pub fn neuspike(&mut self, key: &str, bytes: &[u8], log_ns: i64) -> Result<(), BagError> {
        let id = self.channel(key, None, NEUSPIKE_ENCODING)?;
        self.write(key, id, bytes, log_ns, log_ns)
    }

    fn write(
        &mut self,
        topic: &str,
        id: u16,
        data: &[u8],
        log_ns: i64,
        publish_ns: i64,
    ) -> Result<(), BagError> {
        let seq = self.channels.get_mut(topic).map_or(0, |c| {
            c.1 = c.1.wrapping_add(1);
            c.1
        });
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: seq,
            log_time: u64::try_from(log_ns).unwrap_or(0),
            publish_time: u64::try_from(publish_ns).unwrap_or(0),
        };
        self.writer
            .write_to_known_channel(&header, data)
            .map_err(|e| self.err(e))?;
        self.messages += 1;
        Ok(())
    }

    /// Messages recorded so far.
    pub fn messages(&self) -> u64 {
        self.messages
    }

    /// Writes the summary and the index, syncs the file and renames it to its name.
    ///
    /// # Errors
    /// The file could not be written, synced or renamed; it is then left as
    /// [`partial_path`].
    pub fn finish(mut self) -> Result<PathBuf, BagError> {
        self.writer.finish().map_err(|e| self.err(e))?;
        let Bag {
            path,
            partial,
            writer,
            ..
        } = self;
        let err = |e: &dyn std::fmt::Display| BagError {
            path: partial.clone(),
            reason: e.to_string(),
        };
        let file = writer
            .into_inner()
            .into_inner()
            .map_err(|e| err(e.error()))?;
        file.sync_all().map_err(|e| err(&e))?;
        drop(file);
        std::fs::rename(&partial, &path).map_err(|e| err(&e))?;
        Ok(path)
    }
}

/// Where the bag `path` is written until it is finished: `<path>.partial`.
pub fn partial_path(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_os_string();
    name.push(".partial");
    PathBuf::from(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bag_reads_back_with_its_channels_schemas_and_messages() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("sub/run.mcap");
        let mut bag = Bag::create(&path).expect("bag");
        let image = image_definition();
        for i in 0..3u8 {
            bag.ros2(
                "/neuspike/tfp",
                "sensor_msgs/msg/Image",
                &image,
                &[0, 1, 0, 0, i],
                1_000 + i64::from(i),
                2_000,
            )
            .expect("image");
        }
        bag.neuspike("neuspike/live/tfp", b"arrow", 5_000)
            .expect("arrow");
        assert_eq!(bag.messages(), 4);
        let path = bag.finish().expect("finish");

        let bytes = std::fs::read(path).expect("read");
        let mut seen = Vec::new();
        for m in mcap::MessageStream::new(&bytes).expect("mcap") {
            let m = m.expect("message");
            let schema = m
                .channel
                .schema
                .as_ref()
                .map(|s| (s.name.clone(), s.encoding.clone()));
            seen.push((
                m.channel.topic.clone(),
                m.channel.message_encoding.clone(),
                schema,
                m.log_time,
                m.data.to_vec(),
            ));
        }
        assert_eq!(seen.len(), 4);
        assert_eq!(seen[0].0, "/neuspike/tfp");
        assert_eq!(seen[0].1, "cdr");
        assert_eq!(
            seen[0].2,
            Some(("sensor_msgs/msg/Image".to_string(), "ros2msg".to_string()))
        );
        assert_eq!((seen[2].3, seen[2].4.clone()), (1_002, vec![0, 1, 0, 0, 2]));
        assert_eq!(seen[3].1, NEUSPIKE_ENCODING);
        assert_eq!(seen[3].2, None);
        assert!(image.contains("MSG: builtin_interfaces/Time"));
        assert!(!partial_path(&dir.path().join("sub/run.mcap")).exists());
    }

    #[test]
    fn a_bag_not_finished_keeps_its_partial_name_and_its_messages() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("run.mcap");
        let mut bag = Bag::create(&path).expect("bag");
        for i in 0..3 {
            bag.neuspike("neuspike/live/tfp", b"arrow", 1_000 + i)
                .expect("arrow");
        }
        // The node failed: the bag is dropped, never finished.
        drop(bag);
        assert!(!path.exists(), "an unfinished bag under its own name");
        let bytes = std::fs::read(partial_path(&path)).expect("the partial bag");
        let recovered = mcap::MessageStream::new(&bytes)
            .expect("mcap")
            .filter(Result::is_ok)
            .count();
        assert_eq!(recovered, 3);
    }
}
