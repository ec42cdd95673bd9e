"""Outputs: everything that takes the live streams out of limbstream, one file per output.

==========================  =====================================================================
module                      what it holds
==========================  =====================================================================
:mod:`.subscription`        the one subscription path every live output reads (pose, stats,
                            segment points, truth), decoded, from a bounded hand-off channel
:mod:`.record`              ``limbstream record``: what crosses the router, to an MCAP file
:mod:`.replay`              ``limbstream replay``: a recording's devices published again
:mod:`.export`              ``limbstream export``: BVH / CSV / npz of a recording or motion file
:mod:`.recording`           the recording file (MCAP layout, writer, reader) record, replay and
                            export share
:mod:`.foxglove`            ``limbstream foxglove``: live skeletons and stats over the Foxglove
                            WebSocket protocol; the skeleton builder recordings use too
:mod:`.vmc`                 ``limbstream vmc``: live bones to VSeeFace/Warudo/VNyan over the VMC
                            protocol (OSC over UDP)
:mod:`.kinds`               which pose frames a live output shows (live first, else exact)
==========================  =====================================================================

A new output is one new module here (reading :class:`.subscription.Subscription` if it is
live) plus its thin command module in ``limbstream/cli/`` registered in
``limbstream.cli.COMMANDS``.
"""
