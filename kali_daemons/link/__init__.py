"""Links: the processes that hold a networked robot's connection, one per robot, beside SIO
(docs/decisions/0015).  ``franka``: an FR3 through libfranka."""
