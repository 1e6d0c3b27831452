//! The DDS side of the ROS 2 node and player: one participant in a domain
//! (RustDDS through ros2-client, pure Rust, no ROS installation), topics
//! under ROS 2's DDS names (`rt/...`, `pkg::msg::dds_::Type_`), and the QoS
//! a ROS 2 node uses for each kind of topic.

use crate::error::Error;
use crate::knobs::Knob;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{Context, ContextOptions, MessageTypeName, Name, Node, NodeName, NodeOptions, QosProfile};
use serde::Serialize;

/// What a topic carries, and so its QoS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TopicKind {
    /// Sensor data (`PointCloud2`): best effort, volatile, the last 5
    /// (ROS 2's sensor-data profile): a late scan is worth less than the
    /// next one.
    Sensor,
    /// `/tf`: reliable, volatile, the last 100 (tf2's broadcaster).
    Tf,
    /// `/tf_static` and other latched state: reliable, transient local, the
    /// last one (tf2's static broadcaster): a late joiner gets it.
    Latched,
    /// State a late joiner needs the recent history of (a robot's map
    /// updates): reliable, transient local, the last this many.
    History(usize),
}

impl TopicKind {
    /// The QoS a ROS 2 node uses for it.
    pub fn qos(self) -> QosProfile {
        let reliable = QosProfile::publisher_default().reliability_reliable(WhenFull::DEFAULT);
        match self {
            TopicKind::Sensor => QosProfile::subscription_default()
                .reliability_best_effort()
                .durability(Durability::Volatile)
                .history(History::KeepLast { depth: 5 }),
            TopicKind::Tf => reliable.durability(Durability::Volatile).history(History::KeepLast { depth: 100 }),
            TopicKind::Latched => {
                reliable.durability(Durability::TransientLocal).history(History::KeepLast { depth: 1 })
            }
            TopicKind::History(n) => {
                reliable.durability(Durability::TransientLocal).history(History::KeepLast { depth: n })
            }
        }
    }
}

fn dds(what: &str, e: impl std::fmt::Debug) -> Error {
    Error::Invalid(format!("DDS: {what}: {e:?}"))
}

/// A node in one DDS domain.
pub struct DdsNode {
    node: Node,
}

impl DdsNode {
    /// A node named `name` (a ROS 2 node name) in domain `domain` (0-232:
    /// its ports must fit RTPS's port formula).
    pub fn new(domain: u16, name: &str) -> Result<Self, Error> {
        if domain > 232 {
            return Err(Error::Invalid(format!("{} {domain}: a DDS domain id is 0 to 232", Knob::Domain)));
        }
        let context =
            Context::with_options(ContextOptions::new().domain_id(domain)).map_err(|e| dds("participant", e))?;
        let node_name = NodeName::new("/", name).map_err(|e| dds("node name", e))?;
        let mut node =
            context.new_node(node_name, NodeOptions::new().enable_rosout(false)).map_err(|e| dds("node", e))?;
        // The spinner follows discovery (which readers each writer has
        // matched); it ends when the node is dropped.
        let spinner = node.spinner().map_err(|e| dds("spinner", e))?;
        std::thread::spawn(move || futures::executor::block_on(spinner.spin()));
        Ok(DdsNode { node })
    }

    /// Readers matched by `publisher` (one of this node's).
    pub fn readers<T: Serialize>(&self, publisher: &ros2_client::Publisher<T>) -> usize {
        publisher.get_subscription_count(&self.node)
    }

    /// A publisher of `T` (ROS type `package/msg/Type`) on `topic` (an
    /// absolute ROS 2 name such as `/tf`).
    pub fn publisher<T: Serialize>(
        &mut self,
        topic: &str,
        (package, type_name): (&str, &str),
        kind: TopicKind,
    ) -> Result<ros2_client::Publisher<T>, Error> {
        let (namespace, base) = split_name(topic)?;
        let name = Name::new(namespace, base).map_err(|e| dds(&format!("topic name {topic}"), e))?;
        let qos = kind.qos();
        let t = self
            .node
            .create_topic(&name, MessageTypeName::new(package, type_name), &qos)
            .map_err(|e| dds(&format!("topic {topic}"), e))?;
        self.node.create_publisher::<T>(&t, None).map_err(|e| dds(&format!("publisher on {topic}"), e))
    }
}

impl DdsNode {
    /// A subscription to `T` (ROS type `package/msg/Type`) on `topic`, with
    /// the QoS of `kind`.
    pub fn subscription<T: serde::de::DeserializeOwned + 'static>(
        &mut self,
        topic: &str,
        (package, type_name): (&str, &str),
        kind: TopicKind,
    ) -> Result<ros2_client::Subscription<T>, Error> {
        let (namespace, base) = split_name(topic)?;
        let name = Name::new(namespace, base).map_err(|e| dds(&format!("topic name {topic}"), e))?;
        let t = self
            .node
            .create_topic(&name, MessageTypeName::new(package, type_name), &kind.qos())
            .map_err(|e| dds(&format!("topic {topic}"), e))?;
        self.node.create_subscription::<T>(&t, None).map_err(|e| dds(&format!("subscription to {topic}"), e))
    }

    /// Writers matched by `subscription` (one of this node's).
    pub fn writers<T: 'static>(&self, subscription: &ros2_client::Subscription<T>) -> usize {
        subscription.get_publisher_count(&self.node)
    }
}

/// `/a/b/c` as (`/a/b`, `c`); `/tf` as (`/`, `tf`).
fn split_name(topic: &str) -> Result<(&str, &str), Error> {
    let bad = || Error::Invalid(format!("topic `{topic}`: not an absolute ROS 2 name such as /robot_0/points"));
    if !topic.starts_with('/') {
        return Err(bad());
    }
    let i = topic.rfind('/').ok_or_else(bad)?;
    let (ns, base) = (if i == 0 { "/" } else { &topic[..i] }, &topic[i + 1..]);
    if ns.contains("//") || ns.ends_with('/') && ns.len() > 1 {
        return Err(bad());
    }
    if base.is_empty() || !base.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(bad());
    }
    Ok((ns, base))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topic_names_split_into_namespace_and_base() {
        assert_eq!(split_name("/tf").unwrap(), ("/", "tf"));
        assert_eq!(split_name("/robot_0/points").unwrap(), ("/robot_0", "points"));
        assert_eq!(split_name("/a/b/c").unwrap(), ("/a/b", "c"));
        for bad in ["tf", "/", "/a/", "/a b"] {
            assert!(split_name(bad).is_err(), "{bad}");
        }
    }
}
