"""The time service: the common time base of the devices (``limbstream clock``)."""
