"""The scoring core: the protocol every study and every user shares, owned once.

The rollouts on the vector environment (:mod:`.montecarlo`), the raw environment a policy is
scored on (:mod:`.environment`), the policies behind one interface (:mod:`.policies`), one score
record (:mod:`.evaluate`), each task's reference curve and the paired gap to it
(:mod:`.reference`), the protocol across tasks (:mod:`.suite`) and rliable's aggregates
(:mod:`.aggregate`), the statistics (:mod:`.stats`), the committed files (:mod:`.files`,
:mod:`.versions`), the command lines' shared parts (:mod:`.cli`, :mod:`.commands`), the log
(:mod:`.logs`) and the reports' shared parts (:mod:`.score_table`, :mod:`.figures`). The core
imports no wing (``tests/test_architecture.py``).
"""
