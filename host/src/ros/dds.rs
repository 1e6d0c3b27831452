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
    /// Sensor data read reliably: reliable, volatile, the last 5. Every
    /// scan of a reliable driver arrives (a best-effort driver's never:
    /// DDS matches no reliable reader to a best-effort writer).
    ReliableSensor,
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
            TopicKind::ReliableSensor => {
                reliable.durability(Durability::Volatile).history(History::KeepLast { depth: 5 })
            }
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
    context: Context,
    /// This node's endpoints: DDS topic name, a reader (or a writer), QoS.
    endpoints: Vec<(String, bool, QosProfile)>,
}

/// A remote endpoint on one of this node's topics whose QoS cannot match
/// its own: DDS matches neither way, and nothing flows.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct QosMismatch {
    /// The ROS topic.
    pub topic: String,
    /// The remote endpoint (its GUID).
    pub remote: String,
    /// What does not match, said as a ROS 2 user would read it.
    pub what: String,
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
        Ok(DdsNode { node, context, endpoints: Vec::new() })
    }

    /// Readers matched by `publisher` (one of this node's).
    pub fn readers<T: Serialize>(&self, publisher: &ros2_client::Publisher<T>) -> usize {
        publisher.get_subscription_count(&self.node)
    }

    /// `topic` (an absolute ROS 2 name such as `/tf`) of ROS type
    /// `package/msg/Type` with the QoS of `kind`, its endpoint (a reader
    /// or a writer) recorded for [`DdsNode::qos_mismatches`].
    fn topic(
        &mut self,
        topic: &str,
        (package, type_name): (&str, &str),
        kind: TopicKind,
        reader: bool,
    ) -> Result<ros2_client::dds::rustdds::Topic, Error> {
        let (namespace, base) = split_name(topic)?;
        let name = Name::new(namespace, base).map_err(|e| dds(&format!("topic name {topic}"), e))?;
        let qos = kind.qos();
        self.endpoints.push((format!("rt{topic}"), reader, qos.clone()));
        self.node
            .create_topic(&name, MessageTypeName::new(package, type_name), &qos)
            .map_err(|e| dds(&format!("topic {topic}"), e))
    }

    /// A publisher of `T` (ROS type `package/msg/Type`) on `topic` (an
    /// absolute ROS 2 name such as `/tf`).
    pub fn publisher<T: Serialize>(
        &mut self,
        topic: &str,
        ros_type: (&str, &str),
        kind: TopicKind,
    ) -> Result<ros2_client::Publisher<T>, Error> {
        let t = self.topic(topic, ros_type, kind, false)?;
        self.node.create_publisher::<T>(&t, None).map_err(|e| dds(&format!("publisher on {topic}"), e))
    }

    /// A subscription to `T` (ROS type `package/msg/Type`) on `topic`, with
    /// the QoS of `kind`.
    pub fn subscription<T: serde::de::DeserializeOwned + 'static>(
        &mut self,
        topic: &str,
        ros_type: (&str, &str),
        kind: TopicKind,
    ) -> Result<ros2_client::Subscription<T>, Error> {
        let t = self.topic(topic, ros_type, kind, true)?;
        self.node.create_subscription::<T>(&t, None).map_err(|e| dds(&format!("subscription to {topic}"), e))
    }

    /// The remote endpoints discovered on this node's topics whose QoS
    /// cannot match this node's (DDS's compatibility rules: a reliable
    /// reader takes no best-effort writer, a transient-local reader no
    /// volatile writer, ...): reported, since DDS drops them silently.
    pub fn qos_mismatches(&self) -> Vec<QosMismatch> {
        use ros2_client::dds::rustdds::QosPolicies;
        let participant = self.context.domain_participant();
        let mut found = Vec::new();
        let ros = |dds: &str| dds.strip_prefix("rt").unwrap_or(dds).to_string();
        for w in participant.discovered_writers() {
            let t = &w.publication_topic_data;
            for (_, _, ours) in self.endpoints.iter().filter(|(n, reader, _)| *reader && n == t.topic_name()) {
                let (offered, requested) = (t.qos(), QosPolicies::from(ours));
                if let Some(p) = offered.compliance_failure_wrt(&requested) {
                    let what = format!(
                        "a writer offers {} where this node's reader asks {}",
                        said(p, &offered),
                        said(p, &requested)
                    );
                    found.push(QosMismatch { topic: ros(t.topic_name()), remote: format!("{:?}", t.key), what });
                }
            }
        }
        for r in participant.discovered_readers() {
            let t = &r.subscription_topic_data;
            for (_, _, ours) in self.endpoints.iter().filter(|(n, reader, _)| !*reader && n == t.topic_name()) {
                let (offered, requested) = (QosPolicies::from(ours), t.qos());
                if let Some(p) = offered.compliance_failure_wrt(&requested) {
                    let what = format!(
                        "a reader asks {} where this node's writer offers {}",
                        said(p, &requested),
                        said(p, &offered)
                    );
                    found.push(QosMismatch { topic: ros(t.topic_name()), remote: format!("{:?}", t.key()), what });
                }
            }
        }
        found.sort();
        found.dedup();
        found
    }

    /// Writers matched by `subscription` (one of this node's).
    pub fn writers<T: 'static>(&self, subscription: &ros2_client::Subscription<T>) -> usize {
        subscription.get_publisher_count(&self.node)
    }
}

/// What `q` sets of the policy `p`, as a ROS 2 user names it.
fn said(p: ros2_client::dds::rustdds::dds::qos::QosPolicyId, q: &ros2_client::dds::rustdds::QosPolicies) -> String {
    use ros2_client::dds::rustdds::dds::qos::QosPolicyId as P;
    use ros2_client::dds::rustdds::policy::{Durability as D, Reliability as R};
    match p {
        P::Reliability => match q.reliability() {
            Some(R::Reliable { .. }) => "reliable".into(),
            Some(R::BestEffort) | None => "best effort".into(),
        },
        P::Durability => match q.durability() {
            Some(D::TransientLocal) => "transient local".into(),
            Some(D::Transient) => "transient".into(),
            Some(D::Persistent) => "persistent".into(),
            Some(D::Volatile) | None => "volatile".into(),
        },
        other => format!("another {other:?} policy"),
    }
}

/// Now, as a ROS stamp (wall clock).
pub fn stamp_now() -> crate::sources::ros_msgs::Time {
    let d = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
    crate::sources::ros_msgs::Time { sec: i32::try_from(d.as_secs()).unwrap_or(i32::MAX), nanosec: d.subsec_nanos() }
}

/// `t` (`T_parent_child`) as a stamped `/tf` edge.
pub fn edge(
    stamp: crate::sources::ros_msgs::Time,
    parent: String,
    child: String,
    t: &nalgebra::Isometry3<f64>,
) -> crate::sources::ros_msgs::TransformStamped {
    use crate::sources::ros_msgs::{Header, TransformStamped};
    let transform = crate::sources::recording::transform_of(&t.to_homogeneous());
    TransformStamped { header: Header { stamp, frame_id: parent }, child_frame_id: child, transform }
}

/// A publication that failed, naming the topic.
pub fn published(what: &str, e: impl std::fmt::Debug) -> Error {
    Error::Invalid(format!("DDS: publishing {what}: {e:?}"))
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
