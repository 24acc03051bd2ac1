from rovslam.cli import main

main()
