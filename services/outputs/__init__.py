"""Outputs: everything that takes the live streams out of limbstream, one file per output.

==========================  =====================================================================
module                      what it holds
==========================  =====================================================================
:mod:`.subscription`        the one subscription path every live output reads (pose, stats,
                            segment points, truth), decoded, from a bounded hand-off channel
:mod:`.record`              ``limbstream record``: what crosses the router, to an MCAP file
:mod:`.replay`              ``limbstream replay``: a recording's devices published again
:mod:`.export`              ``limbstream export``: BVH / CSV / npz of a recording or motion file
==========================  =====================================================================

A new output is one new module here (reading :class:`.subscription.Subscription` if it is
live) plus its thin command module in ``limbstream/cli/`` registered in
``limbstream.cli.COMMANDS``.
"""
