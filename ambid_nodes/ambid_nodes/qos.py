"""QoS profiles of the ambid topics, one home for all nodes."""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# lock-step samples: nothing may be lost, the loop waits for each answer
LOOP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                  durability=DurabilityPolicy.VOLATILE)
# measurement and excitation blocks: reliable, a few seconds of blocks queued
BLOCKS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
# descriptions and designs: latched, a late subscriber still gets the last one
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
# status: the latest is what matters, latched for late joiners
STATUS = LATCHED
# events: a session's history, latched
EVENTS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
# /clock as ROS publishes it
CLOCK = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                   durability=DurabilityPolicy.VOLATILE)

# a session's roster (ambid_msgs/SessionMember on `session`): one latched message per node
MEMBERS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def subscription(profile: QoSProfile) -> QoSProfile:
    """The profile an ambid node subscribes with: ``profile``'s reliability and durability, KEEP_ALL.

    A KEEP_LAST reader history drops its oldest unread message when a burst
    overflows it: a flood of foreign messages on a loop topic pushed the
    genuine y[k] or ic[k] out of a depth of 100 before the node took it, and the
    lock-step loop waited for it until its 2 s timeout. KEEP_ALL keeps every
    message until the node takes it; a full history (Fast DDS's resource limits)
    makes a reliable writer wait and send again, so a flood slows the node down
    and loses nothing of a reliable publisher.
    """
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=profile.reliability,
                      durability=profile.durability)
