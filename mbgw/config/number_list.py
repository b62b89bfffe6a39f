"""Lists of numbers as the options and the file write them: '1,5,200-210'."""
import re

from mbgw.errors import ConfigError


def parse_number_list(option: str, text: str, low: int, high: int) -> tuple[int, ...]:
    """'1,5,200-210' (commas or spaces between items, N-M for a range) -> (1, 5, 200, ..., 210),
    sorted, each number checked against low..high."""
    numbers: set[int] = set()
    items = [i for i in re.split(r"[,\s]+", str(text).strip()) if i]
    if not items:
        raise ConfigError(f"{option} {text!r}: empty; expected numbers or ranges, e.g. 1,5,200-210")
    for item in items:
        match = re.fullmatch(r"(\d+)(?:-(\d+))?", item)
        if not match:
            raise ConfigError(f"{option} {text!r}: {item!r} is not a number or a range N-M")
        first, last = int(match[1]), int(match[2] or match[1])
        if first > last:
            raise ConfigError(f"{option} {text!r}: range {item} runs backwards")
        for number in (first, last):
            if not low <= number <= high:
                raise ConfigError(f"{option} {text!r}: {number} out of range {low}..{high}")
        numbers.update(range(first, last + 1))
    return tuple(sorted(numbers))


def number_list_text(numbers) -> str:
    """(1, 5, 200, ..., 210) -> '1,5,200-210': what parse_number_list reads."""
    parts: list[str] = []
    for number in sorted(numbers):
        if parts and number == int(parts[-1].rsplit("-", 1)[-1]) + 1:
            parts[-1] = f"{parts[-1].split('-')[0]}-{number}"
        else:
            parts.append(str(number))
    return ",".join(parts)
