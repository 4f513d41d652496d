"""LatestSent (nbv_prob_cnn/ros/latest_sent.py): when the integrator sends its latest grid or cloud again."""

from nbv_prob_cnn.ros.latest_sent import LatestSent


def test_an_item_goes_out_once_while_the_same_subscribers_listen():
    sent = LatestSent()
    first, second = object(), object()
    assert not sent.due(None, 3)  # nothing yet
    assert not sent.due(first, 0)  # nobody listens
    assert sent.due(first, 1)
    sent.sent(first, 1)
    assert not sent.due(first, 1)
    assert sent.due(second, 1)  # a new item
    sent.sent(second, 1)
    assert not sent.due(second, 1)


def test_a_subscriber_that_joins_gets_the_current_item_again():
    sent = LatestSent()
    item = object()
    sent.sent(item, 1)
    assert sent.due(item, 2)  # one more listens
    sent.sent(item, 2)
    assert not sent.due(item, 1)  # one left: nothing to send, and the count kept drops
    assert sent.due(item, 2)  # so the next one to join is new
    sent.sent(item, 2)
    assert not sent.due(item, 0)  # everyone left
    assert sent.due(item, 1)  # whoever comes next gets it


def test_items_are_told_apart_by_identity_not_equality():
    sent = LatestSent()
    grid, stamp = [0, 1], 7
    sent.sent((grid, stamp), 1)
    assert sent.due((grid, stamp), 1)  # an equal but new (grid, stamp) pair goes out
