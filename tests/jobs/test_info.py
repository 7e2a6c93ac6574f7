"""``jobs.info``: the UTC date printed beside an epoch stamp, and none beside a clock that cannot be a date."""

from lio_cli.jobs.info import utc_date


def test_an_epoch_stamp_is_a_utc_date_to_the_millisecond():
    assert utc_date(1_700_000_000_123_956_789) == "2023-11-14T22:13:20.123Z"  # truncated, as the seconds printed
    assert utc_date(946_684_800 * 10**9) == "2000-01-01T00:00:00.000Z"


def test_a_clock_since_boot_or_simulation_start_has_no_date():
    assert utc_date(47 * 10**9) is None  # robot_localization's jackal.bag starts at 47 s
    assert utc_date(946_684_799 * 10**9) is None and utc_date(None) is None
