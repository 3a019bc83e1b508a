"""The main() of every ambid node: init, spin with an EventsExecutor, shut down cleanly."""

from __future__ import annotations

import contextlib
import gc
import json
import os
import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.task import Future

from ambid_nodes.parameters import ParameterError

SUMMARY_PREFIX = "AMBID_SUMMARY "
# set by a supervising command (ambid_nodes.supervisor) to its pid: the node dies with it
DIE_WITH_PARENT_ENV = "AMBID_DIE_WITH_PARENT"
_PR_SET_PDEATHSIG = 1


def die_with_parent(environ=os.environ) -> None:
    """Where ``AMBID_DIE_WITH_PARENT`` names this process's parent, ask the kernel for SIGTERM when the parent
    goes (Linux), so a node never outlives the command that started it, even a ``kill -9`` of that command. A
    parent already gone by now: SIGTERM at once."""
    parent = environ.get(DIE_WITH_PARENT_ENV, "")
    if not parent.isdigit() or not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):  # pragma: no cover - not Linux after all
        return
    if os.getppid() != int(parent):  # it went before the request was made
        os.kill(os.getpid(), signal.SIGTERM)


def apply_network_defaults(environ=os.environ) -> str:
    """Safe DDS default: discovery on this host only unless the user opened it.

    Sets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` when it is unset or empty (ROS 2 Jazzy's own
    default is SUBNET); a value the user set (SUBNET, SYSTEM_DEFAULT, OFF) and ``ROS_STATIC_PEERS``
    are kept. Returns a one-line description of the node's networking for its log.
    """
    if not environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE"):
        environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    peers = environ.get("ROS_STATIC_PEERS", "")
    security = "on" if environ.get("ROS_SECURITY_ENABLE", "").lower() == "true" else "off"
    return (f"ROS_DOMAIN_ID={environ.get('ROS_DOMAIN_ID', '0')}, discovery range "
            f"{environ['ROS_AUTOMATIC_DISCOVERY_RANGE']}" + (f", static peers {peers}" if peers else "")
            + f", SROS2 security {security}")


def spin_until_done(executor, future, context=None) -> None:
    """Spin until ``future`` completes or the context shuts down (SIGINT, SIGTERM).

    The EventsExecutor of rclpy 7.1 misses a future completed inside a
    callback, and a shutdown of its context, when it spins without a timeout
    (``spin()`` ignores SIGINT and busy-waits), so it wakes up to look.

    The set-up's objects (modules, nodes, models) live as long as the run;
    frozen while it spins, the cyclic garbage collector no longer walks them
    on every full collection (~3 % of a lock-step loop's time otherwise).
    """
    with gc_frozen():
        while not future.done() and rclpy.ok(context=context):
            executor.spin_until_future_complete(future, timeout_sec=0.5)


@contextlib.contextmanager
def gc_frozen():
    """Within: every object alive on entry is out of the cyclic garbage collector's sight (see spin_until_done)."""
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


FLUSH_S = 2.0  # at the end of a finished run, the most a node waits for its last messages to be acknowledged


def flush_publishers(node, timeout_s: float = FLUSH_S) -> bool:
    """Wait (at most ``timeout_s`` in all) until every reliable reader has acknowledged what ``node``
    published: a node that ends its run by itself exits next, and a final status, event or block still in
    flight would die with its writer (a loaded machine's readers lag). False if the time ran out."""
    from rclpy.duration import Duration

    end = time.monotonic() + timeout_s
    for pub in list(node.publishers):
        left = end - time.monotonic()
        if left <= 0:
            return False
        try:
            if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
                return False
        except Exception:  # noqa: BLE001 - a middleware without the call: nothing to wait for
            continue
    return True


def run_single(node_class, args=None) -> int:
    """Run one node until it finishes (its ``finished`` future completes) or is interrupted.

    Exit codes: 0 done, 1 the node reported failure, 2 bad parameters, 130 interrupted.
    A node with a ``finished`` future prints one line ``AMBID_SUMMARY {json}`` of its
    result for a supervising script.
    """
    die_with_parent()
    network = apply_network_defaults()  # before rclpy.init: the middleware reads it there
    try:
        rclpy.init(args=args)
    except Exception as exc:  # noqa: BLE001 - rcl reports malformed --ros-args and YAML files this way
        print(f"{node_class.__name__}: cannot start: {exc}. Check the --ros-args and the parameter YAML file.",
              file=sys.stderr)
        return 2
    executor = EventsExecutor()
    code = 0
    node = None
    try:
        node = node_class()
        node.get_logger().info(f"networking: {network}")
        executor.add_node(node)
        finished = getattr(node, "finished", None)
        spin_until_done(executor, finished if finished is not None else Future())
        if finished is not None and finished.done():
            flush_publishers(node)
            summary = finished.result()
            if summary is not None:
                print(SUMMARY_PREFIX + json.dumps(summary), flush=True)
                code = 0 if summary.get("state") == "done" else 1
    except ParameterError as exc:
        if rclpy.ok():
            print(f"error: {exc}", file=sys.stderr)
            code = 2
        else:  # SIGINT/SIGTERM shut the context down while a parameter was declared: rcl refused its event
            code = 130
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 130
    except Exception:
        if rclpy.ok():
            raise
        code = 130  # SIGINT/SIGTERM shut the context down while the node was being built: rcl refuses
    finally:
        executor.shutdown()
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code
