"""The fault suite of ``ennc-ql chaos`` (:mod:`ennc_ql.chaos`). A real cluster of OS processes trains while faults are
injected; the reliability contract of docs/reference/protocol.md is then checked from outside and the figures are
printed.

The cluster: ``ennc-ql router`` on a free loopback port, and the learner and N actors as its clients (so the router
can be restarted under them). With ``--secure`` (the default) every process has its own certificate, password and
access-control identity (``ennc-ql secure init``'s files, in ``RUN/secure``), and chaos holds one more identity,
``mallory``: authenticated, and played by chaos as a hostile peer. A zenoh session of chaos's own (the ``observer``
identity) records every policy version on the wire and the latest Status of every process.

Once the first policy is checkpointed, one fault every ``--fault-interval`` seconds, in rotation:

=================  ===============================================================================================
learner-kill       SIGKILL the learner just after a checkpoint landed (the most unsaved state); restart ``--resume``
router-restart     SIGKILL the router and start it again on the same port
actor-stop         SIGSTOP an actor until the learner counts it gone (past the zenoh lease), then SIGCONT: counted back
actor-kill         SIGKILL an actor (never actor-0 while there are others) and start a new incarnation of it
partition          (network) every packet of an actor's host dropped for the lease + 3 s, then healed: gone, then back
delay              (network) every link 25 ms slower each way for 8 s: the streams keep flowing
loss               (network) 2 % of what every link relays held back 200 ms (a retransmission) for 8 s
poison             seq 0, a batch with NaN rewards at seq 1, then seq 2 on a peer's key: a Reject of 1, an ack of 2
spoof              batches claiming actor-0's id on a peer's own key; secure: puts on actor-0's key itself
unauthenticated    (secure) a session with a valid certificate but no password: refused
wrong-certificate  (secure) a session with the right password but a certificate of another CA: refused
oversize           one 160 MiB put: dropped by zenoh while reassembling it; RSS barely rises, the learner stays up
=================  ===============================================================================================

With a network fault in the rotation every process runs on a host of its own (:mod:`~tools.chaos.network`: a
network namespace per process, veth links to a bridge, Zenoh's shared memory off) and every client reaches the
router through a link proxy of chaos's (:mod:`~tools.chaos.proxy`) on the router's host, where chaos's own sessions
run too; where namespaces cannot be made (not root, no iproute2 or iptables), the network faults are skipped, saying
why. The rotation always completes one round, past ``--duration`` if need be; after that no fault starts once the
duration is over. Then the actors are stopped (each flushes its outbox and prints its final status), then the
learner (it writes ``RUN/report.json``), then the router, and the contract is checked, each check from figures of
different processes: exactly-once storage, every acknowledged visit applied to the final tables and none stale,
policy versions strictly increasing across restarts, the poisoned stream flowing on, nothing stored from hostile
peers, bounded RSS, and with network faults the experience carried by the links (not by shared memory). Exit status
0 if every check holds, 1 if one fails; ``RUN/chaos.json`` holds what ``--json`` prints. Usage::

    ennc-ql chaos                                       # 120 s, secure, every fault, one every 20 s
    ennc-ql chaos --no-secure --duration 90             # plain TCP (the two TLS faults do not apply)
    ennc-ql chaos --soak 2h --faults learner-kill,router-restart,oversize
    sudo ennc-ql chaos --faults partition,delay,loss    # the network faults alone (root: namespaces, iptables)
    ennc-ql chaos --json --actors 3 --actor-arenas 64 --learner-min-tuples 20000
"""

# The package, by role (its command is ennc_ql.chaos): options (the faults by name, the defaults, their parsers),
# run (the run: its cluster, started with tools.cluster's pieces, the rotation, the drain), faults (each fault),
# observe (chaos's read-only session, RSS, waiting), peers (the hostile peer), network (the hosts: namespaces, links,
# partitions), proxy (the links' delay and loss), checks (the contract checked from the figures, and the table).

from __future__ import annotations

from tools.chaos.checks import Check, Evidence, figures_and_checks, results_table
from tools.chaos.options import FAULTS, SECURE_ONLY, ChaosOptions, parse_duration, parse_faults
from tools.chaos.run import Chaos

__all__ = [
    "FAULTS",
    "SECURE_ONLY",
    "Chaos",
    "ChaosOptions",
    "Check",
    "Evidence",
    "figures_and_checks",
    "parse_duration",
    "parse_faults",
    "results_table",
]
