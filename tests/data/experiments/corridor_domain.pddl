; A hand-written test task for ippc.experiments.fast_downward's runner (not the baseline's
; PDDL, which the knowledge base generates): three rooms, moving costs what it says.
(define (domain corridor)
  (:requirements :strips :typing :action-costs :conditional-effects :negative-preconditions)
  (:types room)
  (:predicates (at ?r - room) (visited ?r - room))
  (:functions (total-cost) - number (cost ?a ?b - room) - number)
  (:action go
    :parameters (?a ?b - room)
    :precondition (and (at ?a) (not (at ?b)))
    :effect (and (at ?b) (not (at ?a)) (when (at ?a) (visited ?b))
                 (increase (total-cost) (cost ?a ?b)))))
