"""Line threads' names (mbgw.line.supervisor.thread_name): what `ps -L` shows for each line."""
from mbgw.line.supervisor import thread_name


def test_line_serial_keeps_its_name_the_others_are_named_after_their_line():
    assert thread_name("serial") == "mbgw-line"
    assert thread_name("panel") == "mbgw-panel"


def test_a_long_name_is_cut_to_the_kernels_15_characters():
    assert thread_name("boiler-room-meters") == "mbgw-boiler-roo"
