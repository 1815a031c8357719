"""What the person at the cell sees on a landscape tablet: the FMS page's layout, checked in the browser.

A 1024x768 tablet shows 625 px of the page below the browser's bars; headless
Chromium with a 1024x768 window has exactly that viewport. These helpers read the
page's geometry in one script each (the page re-renders from its live feed twice
a second: two separate reads could straddle a render).
"""

from __future__ import annotations

from typing import Any

from selenium.common.exceptions import (
    ElementClickInterceptedException,
    ElementNotInteractableException,
    NoSuchElementException,
    StaleElementReferenceException,
)
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support import expected_conditions as ready
from selenium.webdriver.support.ui import WebDriverWait

FIRST_SCREEN_PX = 625
"""The page's height visible on a 1024x768 tablet below the browser's address and tab bars."""
VERDICTS = ("mark-success", "mark-fail")

Box = tuple[float, float, float, float]  # left, top, right, bottom in the viewport


def on_a_tablet(driver: Any) -> None:
    """A 1024x768 window: the viewport of a landscape tablet's browser (1024x625)."""
    driver.set_window_size(1024, 768)
    width, height = driver.execute_script("return [innerWidth, innerHeight]")
    assert width >= 1000 and height >= FIRST_SCREEN_PX, f"a {width}x{height} viewport is not a tablet's"


def tap(driver: Any, element_id: str, timeout: float = 60) -> None:
    """Click once the button shows and is armed (enabled). A click that lands mid-render is tried again."""
    def clicked(d: Any) -> bool:
        try:
            d.find_element(By.ID, element_id).click()
            return True
        except (ElementNotInteractableException, ElementClickInterceptedException,
                StaleElementReferenceException, NoSuchElementException):
            return False

    WebDriverWait(driver, timeout).until(ready.element_to_be_clickable((By.ID, element_id)))
    WebDriverWait(driver, timeout).until(clicked)


def button_boxes(driver: Any) -> dict[str, Box]:
    """Every button's box (shown or keeping its slot invisible); a button taking no room is left out."""
    boxes: dict[str, list[float]] = driver.execute_script(
        "const out = {};"
        "for (const b of document.querySelectorAll('button[id]')) {"
        "  const r = b.getBoundingClientRect();"
        "  if (r.width > 0 && r.height > 0) out[b.id] = [r.left, r.top, r.right, r.bottom];"
        "}"
        "return out;")
    return {name: (box[0], box[1], box[2], box[3]) for name, box in boxes.items()}


def assert_nothing_moved(before: dict[str, Box], after: dict[str, Box]) -> None:
    """A button that takes room in both states is exactly where it was: none moved under a finger."""
    moved = {name: (before[name], after[name]) for name in before.keys() & after.keys() if before[name] != after[name]}
    assert not moved, f"buttons moved between two states of the page: {moved}"


def overlaps(a: Box, b: Box) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def assert_in_first_screen(driver: Any, element_id: str) -> None:
    """The element is inside the tablet's first screen: not scrolled to, not below the fold."""
    scroll_y, height, box = driver.execute_script(
        "const r = document.getElementById(arguments[0]).getBoundingClientRect();"
        "return [window.scrollY, innerHeight, [r.left, r.top, r.right, r.bottom]];", element_id)
    assert scroll_y == 0, f"the page was scrolled ({scroll_y} px) to show #{element_id}"
    left, top, right, bottom = box
    assert 0 <= top and bottom <= min(height, FIRST_SCREEN_PX) and 0 <= left and right <= 1024, (
        f"#{element_id} at {box}, outside the first {FIRST_SCREEN_PX} px of a 1024x768 tablet")


def watch_outcome_box(driver: Any, spot: Box) -> None:
    """Record, at every change of the Success/Fail box, what a finger at the centre of ``spot`` would hit.

    A MutationObserver runs after the render that changed the box, before anything
    else can: each record is the state an operator's tap could meet first.
    """
    x, y = (spot[0] + spot[2]) / 2, (spot[1] + spot[3]) / 2
    driver.execute_script(
        "const [x, y] = arguments;"
        "window.outcomeStates = [];"
        "const box = document.getElementById('outcome-box');"
        "const record = () => {"
        "  const under = document.elementFromPoint(x, y);"
        "  window.outcomeStates.push({"
        "    shown: !box.classList.contains('off'),"
        "    rollout: document.getElementById('outcome-rollout').textContent,"
        "    armed: ['mark-success', 'mark-fail'].filter((id) => !document.getElementById(id).disabled),"
        "    under: under ? (under.id || under.className || under.tagName) : null,"
        "    underArmed: !!under && under.tagName === 'BUTTON' && !under.disabled});"
        "};"
        "new MutationObserver(record).observe(box, {subtree: true, childList: true, characterData: true,"
        "  attributes: true, attributeFilter: ['class', 'disabled']});", x, y)


def first_state_showing(driver: Any, rollout: str) -> dict[str, Any]:
    """The first recorded state of the Success/Fail box showing ``rollout`` (e.g. "2/2")."""
    states: list[dict[str, Any]] = driver.execute_script("return window.outcomeStates || [];")
    shown = [s for s in states if s["shown"] and s["rollout"] == rollout]
    assert shown, f"the Success/Fail box never showed rollout {rollout}: {states}"
    return shown[0]


def filter_labels(driver: Any) -> dict[str, str]:
    """Each fleet filter's label text, through the input's own ``labels`` (a <label for=…> or around it)."""
    labels: dict[str, str] = driver.execute_script(
        "const out = {};"
        "for (const input of document.querySelectorAll('.filters input')) {"
        "  const label = input.labels[0];"
        "  out[input.id] = label && label.offsetHeight > 0 ? label.textContent.trim() : '';"
        "}"
        "return out;")
    return labels


def tap_card_away_from_its_name(driver: Any, cell: str) -> None:
    """A tap near the card's bottom right corner, far from the cell's name: the card opens the cell.

    The card itself stays the same element across the live feed's re-renders (its lines are
    redrawn inside it), so the tap lands on it whenever it comes.
    """
    card = driver.find_element(By.ID, f"cell-{cell}")
    width, height = card.size["width"], card.size["height"]
    ActionChains(driver).move_to_element_with_offset(card, width // 2 - 24, height // 2 - 12).click().perform()


def open_card_with_the_keyboard(driver: Any, cell: str, max_tabs: int = 40) -> None:
    """Tab until the card of ``cell`` has the focus, then Enter."""
    for _ in range(max_tabs):
        ActionChains(driver).send_keys(Keys.TAB).perform()
        if driver.execute_script(
                "const card = document.activeElement && document.activeElement.closest('.card');"
                "return !!card && card.id === arguments[0];", f"cell-{cell}"):
            ActionChains(driver).send_keys(Keys.ENTER).perform()
            return
    raise AssertionError(f"{max_tabs} presses of Tab never reached the card of {cell}")
