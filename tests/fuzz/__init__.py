"""Fuzzing for bvm: generators, oracles and a campaign runner.

* `choosers`  -- the source of randomness shared by hypothesis and the seeded campaign loop;
* `buzzgen`   -- random but valid Buzz source programs (docs/language.md#grammar grammar);
* `mutate`    -- byte-level and instruction-level mutations of compiled programs;
* `oracle`    -- the properties: loader robustness, translated-vs-interpreted agreement;
* `campaign`  -- `python -m tests.fuzz.campaign --minutes M --seed S`.
"""
