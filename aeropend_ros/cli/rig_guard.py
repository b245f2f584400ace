"""One graph per rig: the host lock and the ROS graph check of ``aeropend run``.

Before any node starts, a run takes a lock for its rig (namespace) and ROS domain on this host (:func:`claim_rig`)
and looks at the ROS graph for another graph's publishers on the rig's samples and duty topics
(:func:`check_graph_is_free`); either refuses the run, naming the running one and the --rig / ROS_DOMAIN_ID to use
(two graphs on one rig would each drive the other's motor). While the run lasts it keeps looking
(:func:`foreign_publishers`, :func:`refusal_due`): another graph that discovery shows later stops it with the same
refusal.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

from aeropend_core.errors import AeropendError
from aeropend_ros.topics import UNNAMED_NODE, publisher_name


#: Longest wait for the ROS graph to show another graph's nodes before a run starts [s] (the wait ends earlier when
#: the graph has been unchanged for GRAPH_SETTLE s after at least GRAPH_MIN_WAIT s).
GRAPH_WAIT = 6.0
GRAPH_MIN_WAIT = 1.5
GRAPH_SETTLE = 1.0


def _domain_id() -> int:
    try:
        return int(os.environ.get('ROS_DOMAIN_ID', '0') or 0)
    except ValueError:
        return 0


def _rig_words(namespace: str) -> str:
    return f'rig {namespace.strip("/")}' if namespace not in ('', '/') else 'the default rig (no --rig)'


def claim_rig(namespace: str, lock_folder: str | os.PathLike | None = None):
    """Take this host's lock for the graph of the rig in `namespace` on this ROS domain; returns the open file
    (the lock lasts until it is closed or the process ends).

    Raises
    ------
    AeropendError
        Another process holds it: names that process and the --rig / ROS_DOMAIN_ID to use instead.
    """
    import fcntl
    import tempfile
    folder = Path(lock_folder or os.environ.get('XDG_RUNTIME_DIR') or tempfile.gettempdir())
    domain = _domain_id()
    name = namespace.strip('/').replace('/', '-') or 'default'
    path = folder / f'aeropend-graph-domain{domain}-{name}.lock'
    try:
        handle = open(path, 'a+')          # noqa: SIM115 - held open for the whole run: that is the lock
    except OSError:
        handle = open(path)                # another user's lock file: a read-only open can still be locked
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        # The holder writes its name just after taking the lock: two runs started together can find it empty for a
        # moment (seen in a fresh-clone run), so read again for up to a second before saying 'another process'.
        holder = ''
        for _ in range(20):
            handle.seek(0)
            holder = handle.read().strip()
            if holder:
                break
            time.sleep(0.05)
        holder = holder or 'another process'
        handle.close()
        raise AeropendError(
            f'{_rig_words(namespace)} on ROS domain {domain} already has a graph on this host ({holder}): a second '
            'one would drive the same motor and mix both recordings; stop it, or give this run its own --rig NAME '
            '(or another ROS_DOMAIN_ID)') from None
    if handle.writable():
        handle.seek(0)
        handle.truncate()
        handle.write(f'aeropend run, pid {os.getpid()}, started {time.strftime("%Y-%m-%d %H:%M:%S")}')
        handle.flush()
    return handle


def check_graph_is_free(node, namespace: str) -> None:
    """Refuse when the ROS graph already has nodes on this rig's topics (another graph on this host or network).

    A publisher of the rig's samples (a sim or a bridge) or duty commands (an excitation) belongs to another graph;
    subscribers (a recorder, a monitor, Foxglove) only watch and are no conflict. Waits for discovery: until such a
    publisher shows up (refused at once), or the graph has stayed unchanged for GRAPH_SETTLE s after
    GRAPH_MIN_WAIT s, at most GRAPH_WAIT s.

    Raises
    ------
    AeropendError
        Naming the nodes found and the --rig / ROS_DOMAIN_ID to use instead.
    """
    import rclpy

    watched = watched_topics(namespace)
    start = time.monotonic()
    seen, changed = None, start
    while True:
        found = {publisher_name(info) for topic in watched for info in node.get_publishers_info_by_topic(topic)}
        now = time.monotonic()
        if found and (found != {UNNAMED_NODE} or now - start >= GRAPH_WAIT):
            # Discovery may show an endpoint before its node's name: wait for the name, not past the deadline.
            raise graph_in_use(namespace, found - {UNNAMED_NODE} or found, watched)
        names = frozenset(node.get_node_names_and_namespaces())
        if names != seen:
            seen, changed = names, now
        if not found and (now - start >= GRAPH_WAIT or (now - start >= GRAPH_MIN_WAIT and
                                                          now - changed >= GRAPH_SETTLE)):
            return
        rclpy.spin_once(node, timeout_sec=0.1)


def refusal_due(found: set[str], unnamed_for: float) -> bool:
    """Whether a running graph stops for the foreign publishers `found` (names from :func:`foreign_publishers`).

    Discovery can show a foreign endpoint a moment before its node's name; as at start-up, the refusal waits for the
    name (so that it says which node to stop), but not past GRAPH_WAIT s (`unnamed_for` [s]: how long an unnamed
    endpoint has been seen)."""
    return bool(found) and (UNNAMED_NODE not in found or unnamed_for >= GRAPH_WAIT)


def watched_topics(namespace: str) -> tuple[str, str]:
    """The topics only one graph per rig may publish on: the samples and the duty commands."""
    from aeropend_ros import topics
    prefix = namespace.rstrip('/')
    return f'{prefix}/{topics.SAMPLES}', f'{prefix}/{topics.DUTY_COMMAND}'


def graph_in_use(namespace: str, found, watched) -> AeropendError:
    return AeropendError(
        f'{_rig_words(namespace)} on ROS domain {_domain_id()} is already in use: '
        f'{", ".join(sorted(found))} publish on {" / ".join(watched)} (another aeropend run or launch, here '
        'or on the network); a second graph would drive the same motor; stop it, or give this run its own '
        '--rig NAME (or another ROS_DOMAIN_ID)')


def foreign_publishers(nodes, namespace: str) -> set[str]:
    """Nodes publishing on this rig's samples or duty topics besides this run's own `nodes` (empty: none).

    The start-up check (:func:`check_graph_is_free`) can only wait so long for discovery; a graph that discovery
    shows later is found here, while the run lasts. A foreign node may have the same name as one of ours (a sim
    started by hand), so publishers are counted against our own, not matched by name.

    Parameters
    ----------
    nodes : sequence of rclpy.node.Node
        This run's nodes (the first one asks the graph).
    namespace : str [-]
        The rig's namespace.

    Returns
    -------
    set of str
        The fully qualified names of the publishers on a topic that has more publishers than ours.
    """
    found: set[str] = set()
    for topic in watched_topics(namespace):
        infos = nodes[0].get_publishers_info_by_topic(topic)
        ours = sum(1 for node in nodes for publisher in node.publishers if publisher.topic_name == topic)
        if len(infos) > ours:
            found.update(publisher_name(info) for info in infos)
    return found


__all__ = ['GRAPH_WAIT', 'UNNAMED_NODE', 'check_graph_is_free', 'claim_rig', 'foreign_publishers',
           'graph_in_use', 'refusal_due', 'watched_topics']
