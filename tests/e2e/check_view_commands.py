#!/usr/bin/python3
"""The web view's commands, from the page: read-only by default, allowed with --allow-commands.

  check_view_commands.py READ_ONLY_URL ALLOWING_URL

On each server the page (headless Chromium, tests/e2e/cdp.py) waits for the server's hello, then
asks for a tare of node 3, a mode 'stream' of node 3 and a command that does not exist. The
read-only page must not send (its command() says so), and a message sent by hand must be refused
with a reason; the allowing server must answer ok to the two commands and refuse the bad one.
PASS/FAIL lines; exit 1 on any FAIL.
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cdp  # noqa: E402

RESULTS = "window.skinbusView.summary().command_results"


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    ro_url, rw_url = sys.argv[1:]
    fails = 0

    def check(name, cond, detail=""):
        nonlocal fails
        print(("PASS " if cond else "FAIL ") + name + (f": {detail}" if detail else ""))
        fails += 0 if cond else 1

    with cdp.Browser() as browser:
        browser.open(ro_url)
        browser.wait_for("window.skinbusView && window.skinbusView.summary().messages.hello", 20)
        s = browser.evaluate("window.skinbusView.summary()")
        check("a default server's page is read-only", s["read_only"] is True)
        sent = browser.evaluate("window.skinbusView.command(3, 'tare')")
        check("the read-only page does not send commands", sent is False)
        # A page that sends anyway (a modified page, another client) is refused with a reason.
        browser.evaluate("(() => { const s = new WebSocket(`ws://${location.host}/ws`);"
                         " window.handSocket = s; window.handAnswers = [];"
                         " s.onmessage = (e) => { const m = JSON.parse(e.data);"
                         " if (m.type === 'command_result') window.handAnswers.push(m); };"
                         " s.onopen = () => s.send(JSON.stringify("
                         "{type: 'command', node: 3, command: 'tare'})); return true; })()")
        answers = browser.wait_for("window.handAnswers.length && window.handAnswers", 10)
        check("a command sent anyway is refused", answers[0]["ok"] is False and
              "read-only" in answers[0]["detail"], str(answers[0]))

        browser.open(rw_url)
        browser.wait_for("window.skinbusView && window.skinbusView.summary().messages.hello", 20)
        s = browser.evaluate("window.skinbusView.summary()")
        check("a page of a server with --allow-commands may command", s["read_only"] is False)
        check("it sends a tare", browser.evaluate("window.skinbusView.command(3, 'tare')") is True)
        r = browser.wait_for(f"{RESULTS}.length >= 1 && {RESULTS}", 10)
        check("the tare is answered ok", r[0]["ok"] is True and r[0]["command"] == "tare", str(r[0]))
        browser.evaluate("window.skinbusView.command(3, 'mode', 'stream')")
        r = browser.wait_for(f"{RESULTS}.length >= 2 && {RESULTS}", 10)
        check("the mode is answered ok", r[0]["ok"] is True and r[0]["command"] == "mode stream",
              str(r[0]))
        browser.evaluate("window.skinbusView.command(200, 'tare')")
        r = browser.wait_for(f"{RESULTS}.length >= 3 && {RESULTS}", 10)
        check("a command to node 200 is refused with a reason", r[0]["ok"] is False and
              "1..125" in r[0]["detail"], str(r[0]))
        # The buttons are there when a patch is selected.
        browser.evaluate("window.skinbusView.selectPatch(3)")
        buttons = browser.evaluate("[...document.querySelectorAll('#commands button')]"
                                   ".map((b) => b.textContent)")
        check("the selected patch shows its command buttons", buttons == ["tare", "stream", "event", "off"],
              str(buttons))
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
