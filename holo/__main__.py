from holo.app import main

main()
